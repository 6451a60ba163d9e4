/* emcosim's FMI 2.0 framework in C: the FMI functions of a native plant FMU (Model Exchange).
 *
 * The model (emc_framework.h, emc_model.h) supplies variables and equations; this file supplies the state
 * machine of FMI 2.0 section 3.2.3 (the masks of the Reference-FMUs), get/set by value reference, the FMU
 * state, the directional derivatives and logging. The plant is eq. (open-loop elecmech):
 * eta = (q, p, x_e), eta' = f(eta, u) = F grad H + g u.
 *
 * Rules kept by every function: the instance is checked, then every argument, before anything is read;
 * a call outside the state machine is refused with fmi2Error and one log line naming the function and
 * the mode; a non-finite value set, or a state outside the domain, is answered with fmi2Error (or
 * fmi2Discard for derivatives that are not finite, which asks the host's solver for a smaller step) and
 * one log line, never with NaN. Memory is allocated in fmi2Instantiate only (the instance, with a fixed
 * pool of FMU states); the model functions are straight-line code (no loop, no allocation).
 * Co-Simulation is not provided yet: its functions answer fmi2Error.
 */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "emc_framework.h"
#include "emc_model.h"

#define EMC_N EMC_N_STATES
#define EMC_MAGIC 0x656d636fu              /* "emco": a live instance */
#define EMC_STATE_MAGIC 0x656d7374u        /* "emst": a saved FMU state */
#define EMC_STATE_POOL 8                   /* FMU states an instance can hold at once (fmi2GetFMUstate) */
#define EMC_MESSAGE 512

typedef enum {
    M_INSTANTIATED = 1 << 0, M_INITIALIZATION = 1 << 1, M_EVENT = 1 << 2, M_CONTINUOUS = 1 << 3,
    M_TERMINATED = 1 << 4, M_ERROR = 1 << 5
} emc_mode;

/* what an FMU state saves: everything that changes after instantiation */
typedef struct {
    unsigned magic;
    int mode;
    int in_use;
    double time;
    double par[EMC_N_PARAMETERS];
    double x0[EMC_N];
    double rtol;
    double u[EMC_N_INPUTS];
    double x[EMC_N];
} emc_data;

typedef struct {
    unsigned magic;
    fmi2CallbackFunctions functions;
    char name[128];
    int logging;
    emc_data d;
    emc_data pool[EMC_STATE_POOL];
} emc_instance;

static const char *mode_name(int mode)
{
    switch (mode) {
    case M_INSTANTIATED: return "after fmi2Instantiate";
    case M_INITIALIZATION: return "in initialization mode";
    case M_EVENT: return "in event mode";
    case M_CONTINUOUS: return "in continuous-time mode";
    case M_TERMINATED: return "after fmi2Terminate";
    default: return "in the error state";
    }
}

static void log_message(emc_instance *c, fmi2Status status, const char *category, const char *format, ...)
{
    char text[EMC_MESSAGE];
    va_list args;
    if (c == NULL || c->functions.logger == NULL || (status == fmi2OK && !c->logging))
        return;
    va_start(args, format);
    vsnprintf(text, sizeof text, format, args);
    va_end(args);
    c->functions.logger(c->functions.componentEnvironment, c->name, status, category, "%s", text);
}

static fmi2Status fail(emc_instance *c, fmi2Status status, const char *format, ...)
{
    char text[EMC_MESSAGE];
    va_list args;
    va_start(args, format);
    vsnprintf(text, sizeof text, format, args);
    va_end(args);
    log_message(c, status, status == fmi2Discard ? "logStatusDiscard" : "logStatusError", "%s: %s",
                EMC_MODEL_IDENTIFIER, text);
    return status;
}

/* the instance, or NULL (nothing can be logged without one) */
static emc_instance *instance(fmi2Component component)
{
    emc_instance *c = (emc_instance *)component;
    return (c != NULL && c->magic == EMC_MAGIC) ? c : NULL;
}

/* fmi2OK if `function` may be called in the instance's mode (mask), else fmi2Error with one log line */
static fmi2Status allowed(emc_instance *c, const char *function, int mask)
{
    if (c->d.mode & mask)
        return fmi2OK;
    return fail(c, fmi2Error, "%s is not allowed %s", function, mode_name(c->d.mode));
}

#define ENTER(function, mask)                                      \
    emc_instance *c = instance(component);                         \
    if (c == NULL) return fmi2Error;                               \
    if (allowed(c, function, mask) != fmi2OK) return fmi2Error

/* ---- the model ---------------------------------------------------------------------------------- */
static int all_finite(const double *v, size_t n)
{
    size_t i;
    for (i = 0; i < n; i++)
        if (!isfinite(v[i])) return 0;
    return 1;
}

/* Psi(q) > 0 (eq. elec energy): Cholesky of its symmetric part, n_e x n_e */
static int psi_positive(const double *par, const double *x)
{
    double P[EMC_N_INPUTS * EMC_N_INPUTS], L[EMC_N_INPUTS * EMC_N_INPUTS];
    const int n = EMC_N_INPUTS;
    int i, j, k;
    emc_Psi(par, x, NULL, P);
    for (i = 0; i < n; i++)
        for (j = 0; j <= i; j++) {
            double s = 0.5 * (P[i * n + j] + P[j * n + i]);
            for (k = 0; k < j; k++) s -= L[i * n + k] * L[j * n + k];
            if (i == j) {
                if (!(s > 0.0)) return 0;
                L[i * n + i] = sqrt(s);
            } else {
                L[i * n + j] = s / L[j * n + j];
            }
        }
    return 1;
}

/* "" if eta is finite, inside the domain and Psi(q) > 0; else why not (into why) */
static int domain_problem(const double *par, const double *x, char *why, size_t size)
{
    double margin;
    if (!all_finite(x, EMC_N)) {
        snprintf(why, size, "the state is not finite");
        return 1;
    }
    emc_margin(par, x, NULL, &margin);
    if (!(margin > 0.0)) {
        snprintf(why, size, "the state reached the boundary of the admissible domain (margin %.6g)", margin);
        return 1;
    }
    if (!psi_positive(par, x)) {
        snprintf(why, size, "Psi(q) is not positive definite (eq. elec energy)");
        return 1;
    }
    return 0;
}

static void format_state(const double *x, char *text, size_t size)
{
    size_t used = 0;
    int i;
    text[0] = '\0';
    for (i = 0; i < EMC_N && used < size; i++) {
        int w = snprintf(text + used, size - used, "%s%s = %.17g", i ? ", " : "", EMC_STATE_NAMES[i], x[i]);
        if (w < 0) break;
        used += (size_t)w;
    }
}

/* the parameters' conditions (components.parameters) with one log line naming the first violated */
static fmi2Status check_parameters(emc_instance *c, const char *function)
{
    int bad = emc_check_parameters(c->d.par);
    if (bad < 0)
        return fmi2OK;
    return fail(c, fmi2Error, "%s: parameter %s = %.17g violates %s %s (finite, 1e-100 <= |value| <= 1e100 unless 0)",
                function, EMC_PARAMETER_NAMES[bad], c->d.par[bad], EMC_PARAMETER_NAMES[bad],
                EMC_PARAMETER_CONDITIONS[bad]);
}

/* the current state: the initial values before fmi2ExitInitializationMode */
static const double *state(const emc_instance *c)
{
    return (c->d.mode & (M_INSTANTIATED | M_INITIALIZATION)) ? c->d.x0 : c->d.x;
}

/* nominal (q, p, x_e) of a one-degree-of-freedom plant from its parameters alone: the construction of
   components.plant_step.nominal_scale (L the distance to the domain's boundary, force |V'(L)|,
   T = sqrt(m L / F), momentum m L / T, x_e with 1/2 |Psi'(0)| x_e^2 = F) */
static void nominals(const double *par, double *out)
{
#if EMC_N_M == 1 && EMC_N_INPUTS == 1
    double zero[EMC_N] = {0.0, 0.0, 0.0}, at[EMC_N] = {0.0, 0.0, 0.0};
    double L, force, Minv, m, T, dPsi;
    emc_margin(par, zero, NULL, &L);
    L = (isfinite(L) && L > 0.0) ? L : 1.0;
    at[0] = L;
    emc_grad_V(par, at, NULL, &force);
    force = fabs(force);
    if (force == 0.0) force = 1.0;
    emc_M_inv(par, zero, NULL, &Minv);
    m = 1.0 / Minv;
    T = sqrt(m * L / force);
    emc_dPsi(par, zero, NULL, &dPsi);
    dPsi = fabs(dPsi);
    out[0] = L;
    out[1] = m * L / T;
    out[2] = dPsi > 0.0 ? sqrt(2.0 * force / dPsi) : 1.0;
#else
#error "nominals: native FMUs of plants with n_m > 1 or n_e > 1 are not generated yet"
#endif
}

/* ---- common functions --------------------------------------------------------------------------- */
const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component component, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[])
{
    size_t i;
    emc_instance *c = instance(component);
    if (c == NULL) return fmi2Error;
    if (nCategories > 0 && categories == NULL)
        return fail(c, fmi2Error, "fmi2SetDebugLogging: categories is NULL with nCategories = %zu", nCategories);
    for (i = 0; i < nCategories; i++) {
        if (categories[i] == NULL)
            return fail(c, fmi2Error, "fmi2SetDebugLogging: category %zu is NULL", i);
        if (strcmp(categories[i], "logStatusWarning") && strcmp(categories[i], "logStatusDiscard")
            && strcmp(categories[i], "logStatusError") && strcmp(categories[i], "logStatusFatal")
            && strcmp(categories[i], "logAll"))
            return fail(c, fmi2Error, "fmi2SetDebugLogging: unknown log category \"%s\"", categories[i]);
    }
    c->logging = loggingOn ? 1 : 0;
    return fmi2OK;
}

static void reset_data(emc_data *d)
{
    memset(d, 0, sizeof *d);
    d->magic = EMC_STATE_MAGIC;
    d->mode = M_INSTANTIATED;
    memcpy(d->par, EMC_PARAMETER_START, sizeof d->par);
    memcpy(d->x0, EMC_INITIAL_START, sizeof d->x0);
    memcpy(d->u, EMC_INPUT_START, sizeof d->u);
    memcpy(d->x, EMC_INITIAL_START, sizeof d->x);
    d->rtol = EMC_RTOL_START;
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation, const fmi2CallbackFunctions *functions,
                              fmi2Boolean visible, fmi2Boolean loggingOn)
{
    emc_instance *c;
    fmi2CallbackLogger logger = functions != NULL ? functions->logger : NULL;
    void *environment = functions != NULL ? functions->componentEnvironment : NULL;
    const char *name = (instanceName != NULL && instanceName[0] != '\0') ? instanceName : "?";
    (void)fmuResourceLocation;
    (void)visible;
#define REFUSE(...) do { if (logger) logger(environment, name, fmi2Error, "logStatusError", __VA_ARGS__); return NULL; } while (0)
    if (functions == NULL) return NULL;
    if (instanceName == NULL || instanceName[0] == '\0')
        REFUSE("%s: fmi2Instantiate: the instance name is empty", EMC_MODEL_IDENTIFIER);
    if (fmuType != fmi2ModelExchange)
        REFUSE("%s: fmi2Instantiate: this native FMU provides Model Exchange only (fmuType %d asked for)",
               EMC_MODEL_IDENTIFIER, (int)fmuType);
    if (fmuGUID == NULL || strcmp(fmuGUID, EMC_GUID) != 0)
        REFUSE("%s: fmi2Instantiate: GUID %s does not match the FMU's %s", EMC_MODEL_IDENTIFIER,
               fmuGUID ? fmuGUID : "(null)", EMC_GUID);
    c = (emc_instance *)calloc(1, sizeof *c);    /* the only allocation of an instance's life */
    if (c == NULL)
        REFUSE("%s: fmi2Instantiate: out of memory", EMC_MODEL_IDENTIFIER);
#undef REFUSE
    c->magic = EMC_MAGIC;
    c->functions = *functions;
    snprintf(c->name, sizeof c->name, "%s", instanceName);
    c->logging = loggingOn ? 1 : 0;
    reset_data(&c->d);
    return c;
}

void fmi2FreeInstance(fmi2Component component)
{
    emc_instance *c = instance(component);
    if (c == NULL) return;
    c->magic = 0;
    free(c);
}

fmi2Status fmi2SetupExperiment(fmi2Component component, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime)
{
    ENTER("fmi2SetupExperiment", M_INSTANTIATED);
    (void)toleranceDefined;
    (void)tolerance;
    if (!isfinite(startTime))
        return fail(c, fmi2Error, "fmi2SetupExperiment: startTime = %g is not finite", startTime);
    if (stopTimeDefined && !(stopTime >= startTime))
        return fail(c, fmi2Error, "fmi2SetupExperiment: stopTime = %g is not >= startTime = %g", stopTime, startTime);
    c->d.time = startTime;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component component)
{
    ENTER("fmi2EnterInitializationMode", M_INSTANTIATED);
    c->d.mode = M_INITIALIZATION;
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component component)
{
    char why[200], where[300];
    ENTER("fmi2ExitInitializationMode", M_INITIALIZATION);
    if (check_parameters(c, "fmi2ExitInitializationMode") != fmi2OK)
        return fmi2Error;
    if (domain_problem(c->d.par, c->d.x0, why, sizeof why)) {
        format_state(c->d.x0, where, sizeof where);
        return fail(c, fmi2Error, "fmi2ExitInitializationMode: the initial state (%s) is not admissible: %s", where, why);
    }
    memcpy(c->d.x, c->d.x0, sizeof c->d.x);
    c->d.mode = M_EVENT;
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component component)
{
    ENTER("fmi2Terminate", M_EVENT | M_CONTINUOUS);
    c->d.mode = M_TERMINATED;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component component)
{
    emc_instance *c = instance(component);
    if (c == NULL) return fmi2Error;
    reset_data(&c->d);
    return fmi2OK;
}

/* ---- get and set -------------------------------------------------------------------------------- */
static fmi2Status check_references(emc_instance *c, const char *function, const fmi2ValueReference vr[], size_t nvr,
                                   const void *value)
{
    size_t i;
    if (nvr == 0) return fmi2OK;
    if (vr == NULL || value == NULL)
        return fail(c, fmi2Error, "%s: vr or value is NULL with nvr = %zu", function, nvr);
    for (i = 0; i < nvr; i++)
        if (vr[i] >= EMC_N_VARIABLES)
            return fail(c, fmi2Error, "%s: value reference %u does not exist (0 to %d)", function, vr[i],
                        EMC_N_VARIABLES - 1);
    return fmi2OK;
}

fmi2Status fmi2GetReal(fmi2Component component, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[])
{
    double dx[EMC_N];
    const double *x;
    int have_dx = 0;
    size_t i;
    ENTER("fmi2GetReal", M_INITIALIZATION | M_EVENT | M_CONTINUOUS | M_TERMINATED);
    if (check_references(c, "fmi2GetReal", vr, nvr, value) != fmi2OK) return fmi2Error;
    x = state(c);
    for (i = 0; i < nvr; i++) {
        const emc_variable *v = &EMC_VARIABLES[vr[i]];
        if ((v->kind == EMC_ENERGY || v->kind == EMC_DERIVATIVE) && (c->d.mode & M_INITIALIZATION)
            && check_parameters(c, "fmi2GetReal") != fmi2OK)
            return fmi2Error;
        switch (v->kind) {
        case EMC_PARAMETER: value[i] = c->d.par[v->index]; break;
        case EMC_INITIAL: value[i] = c->d.x0[v->index]; break;
        case EMC_TOLERANCE: value[i] = c->d.rtol; break;
        case EMC_INPUT: value[i] = c->d.u[v->index]; break;
        case EMC_STATE: value[i] = x[v->index]; break;
        case EMC_ENERGY: emc_H(c->d.par, x, c->d.u, &value[i]); break;
        case EMC_DERIVATIVE:
            if (!have_dx) { emc_f(c->d.par, x, c->d.u, dx); have_dx = 1; }
            value[i] = dx[v->index];
            break;
        }
        if (!isfinite(value[i]))
            return fail(c, fmi2Error, "fmi2GetReal: %s is not finite at t = %.9g s", v->name, c->d.time);
    }
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component component, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[])
{
    size_t i;
    ENTER("fmi2SetReal", M_INSTANTIATED | M_INITIALIZATION | M_EVENT | M_CONTINUOUS);
    if (check_references(c, "fmi2SetReal", vr, nvr, value) != fmi2OK) return fmi2Error;
    for (i = 0; i < nvr; i++) {           /* all checked before any is set */
        const emc_variable *v = &EMC_VARIABLES[vr[i]];
        int fixed = v->kind == EMC_PARAMETER || v->kind == EMC_INITIAL || v->kind == EMC_TOLERANCE;
        if (v->kind != EMC_INPUT && !fixed)
            return fail(c, fmi2Error, "fmi2SetReal: %s is an output and cannot be set", v->name);
        if (fixed && !(c->d.mode & (M_INSTANTIATED | M_INITIALIZATION)))
            return fail(c, fmi2Error, "fmi2SetReal: the parameter %s cannot be set %s", v->name, mode_name(c->d.mode));
        if (!isfinite(value[i]))
            return fail(c, fmi2Error, "fmi2SetReal: %s = %g is not finite", v->name, value[i]);
    }
    for (i = 0; i < nvr; i++) {
        const emc_variable *v = &EMC_VARIABLES[vr[i]];
        switch (v->kind) {
        case EMC_PARAMETER: c->d.par[v->index] = value[i]; break;
        case EMC_INITIAL: c->d.x0[v->index] = value[i]; break;
        case EMC_TOLERANCE: c->d.rtol = value[i]; break;
        case EMC_INPUT: c->d.u[v->index] = value[i]; break;
        default: break;
        }
    }
    return fmi2OK;
}

#define NO_VARIABLES(function, type, constness)                                                       \
    fmi2Status function(fmi2Component component, const fmi2ValueReference vr[], size_t nvr, constness type value[]) \
    {                                                                                                 \
        ENTER(#function, M_INSTANTIATED | M_INITIALIZATION | M_EVENT | M_CONTINUOUS | M_TERMINATED);   \
        (void)value;                                                                                  \
        if (nvr == 0) return fmi2OK;                                                                  \
        if (vr == NULL) return fail(c, fmi2Error, "%s: vr is NULL with nvr = %zu", #function, nvr);   \
        return fail(c, fmi2Error, "%s: value reference %u is not of this type (all are Real)", #function, vr[0]); \
    }
NO_VARIABLES(fmi2GetInteger, fmi2Integer, )
NO_VARIABLES(fmi2GetBoolean, fmi2Boolean, )
NO_VARIABLES(fmi2GetString, fmi2String, )
NO_VARIABLES(fmi2SetInteger, fmi2Integer, const)
NO_VARIABLES(fmi2SetBoolean, fmi2Boolean, const)
NO_VARIABLES(fmi2SetString, fmi2String, const)

/* ---- FMU state: a fixed pool inside the instance (no allocation) ---------------------------------- */
static fmi2Status check_saved(emc_instance *c, const char *function, const emc_data *s)
{
    char why[200];
    int bad;
    if (s->magic != EMC_STATE_MAGIC || !(s->mode & (M_INSTANTIATED | M_INITIALIZATION | M_EVENT | M_CONTINUOUS | M_TERMINATED))
        || (s->mode & (s->mode - 1)))
        return fail(c, fmi2Error, "%s: not an FMU state of %s", function, EMC_MODEL_IDENTIFIER);
    if (!isfinite(s->time) || !all_finite(s->par, EMC_N_PARAMETERS) || !all_finite(s->x0, EMC_N)
        || !isfinite(s->rtol) || !all_finite(s->u, EMC_N_INPUTS))
        return fail(c, fmi2Error, "%s: the FMU state holds values that are not finite", function);
    if (s->mode & (M_EVENT | M_CONTINUOUS | M_TERMINATED)) {
        bad = emc_check_parameters(s->par);
        if (bad >= 0)
            return fail(c, fmi2Error, "%s: the FMU state's parameter %s = %g violates %s %s", function,
                        EMC_PARAMETER_NAMES[bad], s->par[bad], EMC_PARAMETER_NAMES[bad], EMC_PARAMETER_CONDITIONS[bad]);
        if (domain_problem(s->par, s->x, why, sizeof why))
            return fail(c, fmi2Error, "%s: the FMU state's state is not admissible: %s", function, why);
    }
    return fmi2OK;
}

fmi2Status fmi2GetFMUstate(fmi2Component component, fmi2FMUstate *FMUstate)
{
    emc_data *slot = NULL;
    int i;
    ENTER("fmi2GetFMUstate", M_INSTANTIATED | M_INITIALIZATION | M_EVENT | M_CONTINUOUS | M_TERMINATED);
    if (FMUstate == NULL) return fail(c, fmi2Error, "fmi2GetFMUstate: FMUstate is NULL");
    if (*FMUstate != NULL) {                                /* overwrite a state of this instance */
        for (i = 0; i < EMC_STATE_POOL; i++)
            if (*FMUstate == (fmi2FMUstate)&c->pool[i] && c->pool[i].in_use) slot = &c->pool[i];
        if (slot == NULL) return fail(c, fmi2Error, "fmi2GetFMUstate: *FMUstate is not a state of this instance");
    } else {
        for (i = 0; i < EMC_STATE_POOL && slot == NULL; i++)
            if (!c->pool[i].in_use) slot = &c->pool[i];
        if (slot == NULL)
            return fail(c, fmi2Error, "fmi2GetFMUstate: all %d FMU states of this instance are in use (free one "
                        "with fmi2FreeFMUstate)", EMC_STATE_POOL);
    }
    *slot = c->d;
    slot->in_use = 1;
    *FMUstate = (fmi2FMUstate)slot;
    return fmi2OK;
}

static emc_data *pooled(emc_instance *c, fmi2FMUstate s)
{
    int i;
    for (i = 0; i < EMC_STATE_POOL; i++)
        if (s == (fmi2FMUstate)&c->pool[i] && c->pool[i].in_use) return &c->pool[i];
    return NULL;
}

fmi2Status fmi2SetFMUstate(fmi2Component component, fmi2FMUstate FMUstate)
{
    emc_data *s;
    ENTER("fmi2SetFMUstate", M_INSTANTIATED | M_INITIALIZATION | M_EVENT | M_CONTINUOUS | M_TERMINATED);
    s = pooled(c, FMUstate);
    if (s == NULL) return fail(c, fmi2Error, "fmi2SetFMUstate: not an FMU state of this instance");
    if (check_saved(c, "fmi2SetFMUstate", s) != fmi2OK) return fmi2Error;
    c->d = *s;
    c->d.in_use = 0;
    return fmi2OK;
}

fmi2Status fmi2FreeFMUstate(fmi2Component component, fmi2FMUstate *FMUstate)
{
    emc_data *s;
    ENTER("fmi2FreeFMUstate", M_INSTANTIATED | M_INITIALIZATION | M_EVENT | M_CONTINUOUS | M_TERMINATED);
    if (FMUstate == NULL) return fail(c, fmi2Error, "fmi2FreeFMUstate: FMUstate is NULL");
    if (*FMUstate == NULL) return fmi2OK;
    s = pooled(c, *FMUstate);
    if (s == NULL) return fail(c, fmi2Error, "fmi2FreeFMUstate: not an FMU state of this instance");
    s->in_use = 0;
    *FMUstate = NULL;
    return fmi2OK;
}

/* serialized: EMC_GUID (fixed width) then the emc_data bytes */
#define EMC_SERIAL_SIZE (sizeof(EMC_GUID) + sizeof(emc_data))

fmi2Status fmi2SerializedFMUstateSize(fmi2Component component, fmi2FMUstate FMUstate, size_t *size)
{
    ENTER("fmi2SerializedFMUstateSize", M_INSTANTIATED | M_INITIALIZATION | M_EVENT | M_CONTINUOUS | M_TERMINATED);
    if (size == NULL) return fail(c, fmi2Error, "fmi2SerializedFMUstateSize: size is NULL");
    if (pooled(c, FMUstate) == NULL) return fail(c, fmi2Error, "fmi2SerializedFMUstateSize: not an FMU state of this instance");
    *size = EMC_SERIAL_SIZE;
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component component, fmi2FMUstate FMUstate, fmi2Byte serializedState[], size_t size)
{
    emc_data *s;
    ENTER("fmi2SerializeFMUstate", M_INSTANTIATED | M_INITIALIZATION | M_EVENT | M_CONTINUOUS | M_TERMINATED);
    s = pooled(c, FMUstate);
    if (s == NULL) return fail(c, fmi2Error, "fmi2SerializeFMUstate: not an FMU state of this instance");
    if (serializedState == NULL || size != EMC_SERIAL_SIZE)
        return fail(c, fmi2Error, "fmi2SerializeFMUstate: a buffer of %zu bytes is needed", (size_t)EMC_SERIAL_SIZE);
    memcpy(serializedState, EMC_GUID, sizeof(EMC_GUID));
    memcpy(serializedState + sizeof(EMC_GUID), s, sizeof *s);
    return fmi2OK;
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component component, const fmi2Byte serializedState[], size_t size,
                                   fmi2FMUstate *FMUstate)
{
    emc_data d, *slot = NULL;
    int i;
    ENTER("fmi2DeSerializeFMUstate", M_INSTANTIATED | M_INITIALIZATION | M_EVENT | M_CONTINUOUS | M_TERMINATED);
    if (serializedState == NULL || FMUstate == NULL)
        return fail(c, fmi2Error, "fmi2DeSerializeFMUstate: serializedState or FMUstate is NULL");
    if (size != EMC_SERIAL_SIZE || memcmp(serializedState, EMC_GUID, sizeof(EMC_GUID)) != 0)
        return fail(c, fmi2Error, "fmi2DeSerializeFMUstate: not a serialized FMU state of this FMU (%zu bytes)", size);
    memcpy(&d, serializedState + sizeof(EMC_GUID), sizeof d);
    if (check_saved(c, "fmi2DeSerializeFMUstate", &d) != fmi2OK) return fmi2Error;
    if (*FMUstate != NULL) {
        slot = pooled(c, *FMUstate);
        if (slot == NULL) return fail(c, fmi2Error, "fmi2DeSerializeFMUstate: *FMUstate is not a state of this instance");
    } else {
        for (i = 0; i < EMC_STATE_POOL && slot == NULL; i++)
            if (!c->pool[i].in_use) slot = &c->pool[i];
        if (slot == NULL)
            return fail(c, fmi2Error, "fmi2DeSerializeFMUstate: all %d FMU states are in use", EMC_STATE_POOL);
    }
    *slot = d;
    slot->in_use = 1;
    *FMUstate = (fmi2FMUstate)slot;
    return fmi2OK;
}

/* ---- directional derivatives: df/deta = F hess H, df/du = g, dH = grad H, d(state) = seed ------------ */
fmi2Status fmi2GetDirectionalDerivative(fmi2Component component, const fmi2ValueReference vUnknown_ref[], size_t nUnknown,
                                        const fmi2ValueReference vKnown_ref[], size_t nKnown,
                                        const fmi2Real dvKnown[], fmi2Real dvUnknown[])
{
    double J[EMC_N * EMC_N], g[EMC_N * EMC_N_INPUTS], gH[EMC_N], v[EMC_N], du[EMC_N_INPUTS];
    const double *x;
    size_t i;
    int k;
    ENTER("fmi2GetDirectionalDerivative", M_INITIALIZATION | M_EVENT | M_CONTINUOUS | M_TERMINATED);
    if (check_references(c, "fmi2GetDirectionalDerivative", vUnknown_ref, nUnknown, dvUnknown) != fmi2OK
        || check_references(c, "fmi2GetDirectionalDerivative", vKnown_ref, nKnown, dvKnown) != fmi2OK)
        return fmi2Error;
    memset(v, 0, sizeof v);
    memset(du, 0, sizeof du);
    for (i = 0; i < nKnown; i++) {
        const emc_variable *w = &EMC_VARIABLES[vKnown_ref[i]];
        if (!isfinite(dvKnown[i]))
            return fail(c, fmi2Error, "fmi2GetDirectionalDerivative: the seed of %s is not finite", w->name);
        if (w->kind == EMC_STATE) v[w->index] += dvKnown[i];
        else if (w->kind == EMC_INPUT) du[w->index] += dvKnown[i];
        else return fail(c, fmi2Error, "fmi2GetDirectionalDerivative: %s is not a known (a state or an input)", w->name);
    }
    for (i = 0; i < nUnknown; i++) {
        emc_kind kind = EMC_VARIABLES[vUnknown_ref[i]].kind;
        if (kind != EMC_STATE && kind != EMC_ENERGY && kind != EMC_DERIVATIVE)
            return fail(c, fmi2Error, "fmi2GetDirectionalDerivative: %s is not an unknown (an output or a state "
                        "derivative)", EMC_VARIABLES[vUnknown_ref[i]].name);
    }
    if ((c->d.mode & M_INITIALIZATION) && check_parameters(c, "fmi2GetDirectionalDerivative") != fmi2OK)
        return fmi2Error;
    x = state(c);
    emc_jacobian(c->d.par, x, c->d.u, J);
    emc_g(c->d.par, x, c->d.u, g);
    emc_grad_H(c->d.par, x, c->d.u, gH);
    for (i = 0; i < nUnknown; i++) {
        const emc_variable *w = &EMC_VARIABLES[vUnknown_ref[i]];
        double s = 0.0;
        if (w->kind == EMC_STATE) {
            s = v[w->index];
        } else if (w->kind == EMC_ENERGY) {
            for (k = 0; k < EMC_N; k++) s += gH[k] * v[k];
        } else {
            for (k = 0; k < EMC_N; k++) s += J[w->index * EMC_N + k] * v[k];
            for (k = 0; k < EMC_N_INPUTS; k++) s += g[w->index * EMC_N_INPUTS + k] * du[k];
        }
        if (!isfinite(s))
            return fail(c, fmi2Error, "fmi2GetDirectionalDerivative: d %s is not finite at t = %.9g s", w->name, c->d.time);
        dvUnknown[i] = s;
    }
    return fmi2OK;
}

/* ---- Model Exchange ----------------------------------------------------------------------------- */
fmi2Status fmi2EnterEventMode(fmi2Component component)
{
    ENTER("fmi2EnterEventMode", M_EVENT | M_CONTINUOUS);
    c->d.mode = M_EVENT;
    return fmi2OK;
}

fmi2Status fmi2NewDiscreteStates(fmi2Component component, fmi2EventInfo *eventInfo)
{
    char why[200], where[300];
    ENTER("fmi2NewDiscreteStates", M_EVENT);
    if (eventInfo == NULL) return fail(c, fmi2Error, "fmi2NewDiscreteStates: eventInfo is NULL");
    memset(eventInfo, 0, sizeof *eventInfo);
    if (domain_problem(c->d.par, c->d.x, why, sizeof why)) {
        eventInfo->terminateSimulation = fmi2True;
        format_state(c->d.x, where, sizeof where);
        return fail(c, fmi2Error, "at t = %.9g s (%s): %s: the model is not defined beyond it; the simulation must "
                    "end here", c->d.time, where, why);
    }
    return fmi2OK;
}

fmi2Status fmi2EnterContinuousTimeMode(fmi2Component component)
{
    ENTER("fmi2EnterContinuousTimeMode", M_EVENT);
    c->d.mode = M_CONTINUOUS;
    return fmi2OK;
}

fmi2Status fmi2CompletedIntegratorStep(fmi2Component component, fmi2Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi2Boolean *enterEventMode, fmi2Boolean *terminateSimulation)
{
    ENTER("fmi2CompletedIntegratorStep", M_CONTINUOUS);
    (void)noSetFMUStatePriorToCurrentPoint;
    if (enterEventMode == NULL || terminateSimulation == NULL)
        return fail(c, fmi2Error, "fmi2CompletedIntegratorStep: enterEventMode or terminateSimulation is NULL");
    *enterEventMode = fmi2False;
    *terminateSimulation = fmi2False;
    return fmi2OK;
}

fmi2Status fmi2SetTime(fmi2Component component, fmi2Real time)
{
    ENTER("fmi2SetTime", M_EVENT | M_CONTINUOUS);
    if (!isfinite(time)) return fail(c, fmi2Error, "fmi2SetTime: time = %g is not finite", time);
    c->d.time = time;
    return fmi2OK;
}

fmi2Status fmi2SetContinuousStates(fmi2Component component, const fmi2Real x[], size_t nx)
{
    ENTER("fmi2SetContinuousStates", M_CONTINUOUS);
    if (x == NULL || nx != EMC_N)
        return fail(c, fmi2Error, "fmi2SetContinuousStates: %zu values for %d states (or x is NULL)", nx, EMC_N);
    if (!all_finite(x, EMC_N))
        return fail(c, fmi2Error, "fmi2SetContinuousStates: not finite at t = %.9g s; the state is kept", c->d.time);
    memcpy(c->d.x, x, sizeof c->d.x);
    return fmi2OK;
}

fmi2Status fmi2GetDerivatives(fmi2Component component, fmi2Real derivatives[], size_t nx)
{
    char where[300];
    double dx[EMC_N];
    ENTER("fmi2GetDerivatives", M_EVENT | M_CONTINUOUS | M_TERMINATED);
    if (derivatives == NULL || nx != EMC_N)
        return fail(c, fmi2Error, "fmi2GetDerivatives: %zu values asked for, the FMU has %d states (or NULL)", nx, EMC_N);
    emc_f(c->d.par, c->d.x, c->d.u, dx);
    if (!all_finite(dx, EMC_N)) {        /* the host's solver tries a smaller step */
        format_state(c->d.x, where, sizeof where);
        return fail(c, fmi2Discard, "fmi2GetDerivatives at t = %.9g s: not finite at the state %s", c->d.time, where);
    }
    memcpy(derivatives, dx, sizeof dx);
    return fmi2OK;
}

fmi2Status fmi2GetEventIndicators(fmi2Component component, fmi2Real eventIndicators[], size_t ni)
{
    ENTER("fmi2GetEventIndicators", M_INITIALIZATION | M_EVENT | M_CONTINUOUS | M_TERMINATED);
    if (eventIndicators == NULL || ni != 1)
        return fail(c, fmi2Error, "fmi2GetEventIndicators: %zu values asked for, the FMU has 1 (or NULL)", ni);
    emc_margin(c->d.par, state(c), c->d.u, eventIndicators);
    return fmi2OK;
}

fmi2Status fmi2GetContinuousStates(fmi2Component component, fmi2Real x[], size_t nx)
{
    ENTER("fmi2GetContinuousStates", M_INITIALIZATION | M_EVENT | M_CONTINUOUS | M_TERMINATED);
    if (x == NULL || nx != EMC_N)
        return fail(c, fmi2Error, "fmi2GetContinuousStates: %zu values asked for, the FMU has %d states (or NULL)", nx, EMC_N);
    memcpy(x, state(c), sizeof c->d.x);
    return fmi2OK;
}

fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component component, fmi2Real x_nominal[], size_t nx)
{
    double out[EMC_N];
    ENTER("fmi2GetNominalsOfContinuousStates", M_INSTANTIATED | M_EVENT | M_CONTINUOUS | M_TERMINATED);
    if (x_nominal == NULL || nx != EMC_N)
        return fail(c, fmi2Error, "fmi2GetNominalsOfContinuousStates: %zu values asked for, the FMU has %d states (or NULL)",
                    nx, EMC_N);
    if (check_parameters(c, "fmi2GetNominalsOfContinuousStates") != fmi2OK) return fmi2Error;
    nominals(c->d.par, out);
    if (!all_finite(out, EMC_N))
        return fail(c, fmi2Error, "fmi2GetNominalsOfContinuousStates: not finite for these parameters");
    memcpy(x_nominal, out, sizeof out);
    return fmi2OK;
}

/* ---- Co-Simulation: not provided yet (the modelDescription declares Model Exchange only) --------- */
#define NOT_PROVIDED(function)                                                                      \
    {                                                                                               \
        emc_instance *c = instance(component);                                                      \
        if (c == NULL) return fmi2Error;                                                            \
        return fail(c, fmi2Error, "%s: Co-Simulation is not provided by this native FMU", function); \
    }

fmi2Status fmi2SetRealInputDerivatives(fmi2Component component, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[])
{ (void)vr; (void)nvr; (void)order; (void)value; NOT_PROVIDED("fmi2SetRealInputDerivatives") }
fmi2Status fmi2GetRealOutputDerivatives(fmi2Component component, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[])
{ (void)vr; (void)nvr; (void)order; (void)value; NOT_PROVIDED("fmi2GetRealOutputDerivatives") }
fmi2Status fmi2DoStep(fmi2Component component, fmi2Real currentCommunicationPoint, fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint)
{ (void)currentCommunicationPoint; (void)communicationStepSize; (void)noSetFMUStatePriorToCurrentPoint; NOT_PROVIDED("fmi2DoStep") }
fmi2Status fmi2CancelStep(fmi2Component component) NOT_PROVIDED("fmi2CancelStep")
fmi2Status fmi2GetStatus(fmi2Component component, const fmi2StatusKind s, fmi2Status *value)
{ (void)s; (void)value; NOT_PROVIDED("fmi2GetStatus") }
fmi2Status fmi2GetRealStatus(fmi2Component component, const fmi2StatusKind s, fmi2Real *value)
{ (void)s; (void)value; NOT_PROVIDED("fmi2GetRealStatus") }
fmi2Status fmi2GetIntegerStatus(fmi2Component component, const fmi2StatusKind s, fmi2Integer *value)
{ (void)s; (void)value; NOT_PROVIDED("fmi2GetIntegerStatus") }
fmi2Status fmi2GetBooleanStatus(fmi2Component component, const fmi2StatusKind s, fmi2Boolean *value)
{ (void)s; (void)value; NOT_PROVIDED("fmi2GetBooleanStatus") }
fmi2Status fmi2GetStringStatus(fmi2Component component, const fmi2StatusKind s, fmi2String *value)
{ (void)s; (void)value; NOT_PROVIDED("fmi2GetStringStatus") }
