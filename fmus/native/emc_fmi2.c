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
 * Co-Simulation (the end of this file): doStep integrates eta' = f(eta, u(t)) with the input held or the
 * polynomial the master set through fmi2SetRealInputDerivatives (orders 1 to EMC_MAX_ORDER), by RODAS4 with
 * the analytic Jacobian and error control (components.plant_step.GeneralStepper, without the closed-form
 * electrical layer of its PlantStepper); at most EMC_MAX_SUBSTEPS substeps a step.
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
#define EMC_MAX_ORDER 16                   /* input derivative orders fmi2SetRealInputDerivatives takes */
#define EMC_MAX_SUBSTEPS 100000            /* substeps of one doStep (components.plant_step.MAX_SUBSTEPS) */
#define EMC_RTOL_MIN 1e-14                 /* components.plant_step.RTOL_RANGE */
#define EMC_RTOL_MAX 1e-2
#define EMC_TIME_TOLERANCE 1e-12           /* fmus/slave.py: COMMUNICATION_POINT_TOLERANCE */

typedef enum {
    M_INSTANTIATED = 1 << 0, M_INITIALIZATION = 1 << 1, M_EVENT = 1 << 2, M_CONTINUOUS = 1 << 3,
    M_TERMINATED = 1 << 4, M_ERROR = 1 << 5, M_STEP = 1 << 6
} emc_mode;
#define M_ANY (M_INSTANTIATED | M_INITIALIZATION | M_EVENT | M_CONTINUOUS | M_TERMINATED | M_STEP)

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
    /* Co-Simulation */
    int tolerance_defined;
    double tolerance;                          /* fmi2SetupExperiment's */
    double start_time;
    double h_next;                             /* the substep proposed for the next step (0: none yet) */
    int have_u_end;                            /* the input at the end of the last step is in force */
    double u_end[2 * EMC_N_INPUTS];            /* its value and rate */
    double du[EMC_MAX_ORDER][EMC_N_INPUTS];    /* d^(k+1) u / dt^(k+1) set for the next step */
} emc_data;

typedef struct {
    unsigned magic;
    fmi2Type interface;
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
    case M_STEP: return "in step mode (after initialization)";
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

/* a function of one interface only */
#define ONLY(function, kind)                                                                       \
    if (c->interface != kind)                                                                      \
        return fail(c, fmi2Error, "%s is not a function of %s", function,                          \
                    c->interface == fmi2ModelExchange ? "Model Exchange" : "Co-Simulation")

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


#if EMC_N_M == 1 && EMC_N_INPUTS == 1
/* nominal (q, p, x_e) of a one-degree-of-freedom plant from its parameters alone: the construction of
   components.plant_step.nominal_scale (L the distance to the domain's boundary, force |V'(L)|,
   T = sqrt(m L / F), momentum m L / T, x_e with 1/2 |Psi'(0)| x_e^2 = F) */
static void nominals(const double *par, double *out)
{
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
}
#else
/* is q = t e_i (sign +-1) inside the domain (margin > 0 or no boundary)? */
static int inside_along(const double *par, int i, double t)
{
    double eta[EMC_N] = {0.0}, margin;
    eta[i] = t;
    emc_margin(par, eta, NULL, &margin);
    return (isfinite(margin) && margin > 0.0) || margin == INFINITY;
}

/* components.plant_step._boundary_distance along sign e_i: to 1e-3 relative, inf beyond 1e6, nan if q = 0 is
   outside (at most 19 decades and 11 bisections) */
static double boundary_distance(const double *par, int i, double sign)
{
    double low = 0.0, high = 1e-12;
    if (!inside_along(par, i, 0.0)) return NAN;
    while (inside_along(par, i, sign * high)) {
        if (high >= 1e6) return INFINITY;
        low = high;
        high *= 10.0;
    }
    while (high - low > 1e-3 * high) {
        double mid = 0.5 * (low + high);
        if (inside_along(par, i, sign * mid)) low = mid; else high = mid;
    }
    return low;
}

/* components.plant_step._nominal_scale_general: the one-degree-of-freedom construction per axis */
static void nominals(const double *par, double *out)
{
    const int m = EMC_N_M, e = EMC_N_INPUTS;
    double zero[EMC_N] = {0.0}, at[EMC_N], grad[EMC_N_M], Minv[EMC_N_M * EMC_N_M], dPsi[EMC_N_M * EMC_N_INPUTS * EMC_N_INPUTS];
    double L[EMC_N_M], force[EMC_N_M], mass[EMC_N_M];
    int i, j, k;
    emc_M_inv(par, zero, NULL, Minv);
    for (i = 0; i < m; i++) {
        double d = fmin(boundary_distance(par, i, 1.0), boundary_distance(par, i, -1.0)), F;
        L[i] = (isfinite(d) && d > 0.0) ? d : 1.0;
        for (k = 0; k < EMC_N; k++) at[k] = 0.0;
        at[i] = L[i];
        emc_grad_V(par, at, NULL, grad);
        F = fabs(grad[i]);
        force[i] = (isfinite(F) && F > 0.0) ? F : 1.0;
        mass[i] = Minv[i * m + i] > 0.0 ? 1.0 / Minv[i * m + i] : 1.0;
        out[i] = L[i];
        out[m + i] = mass[i] * L[i] / sqrt(mass[i] * L[i] / force[i]);
    }
    emc_dPsi(par, zero, NULL, dPsi);
    for (j = 0; j < e; j++) {
        int best = 0;
        for (k = 1; k < m; k++)
            if (fabs(dPsi[(k * e + j) * e + j]) > fabs(dPsi[(best * e + j) * e + j])) best = k;
        out[2 * m + j] = fabs(dPsi[(best * e + j) * e + j]) > 0.0
                             ? sqrt(2.0 * force[best] / fabs(dPsi[(best * e + j) * e + j])) : 1.0;
    }
    for (k = 0; k < EMC_N; k++)
        if (!(isfinite(out[k]) && out[k] > 0.0)) out[k] = 1.0;
}
#endif

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
    if (fmuType != fmi2ModelExchange && fmuType != fmi2CoSimulation)
        REFUSE("%s: fmi2Instantiate: fmuType %d is neither fmi2ModelExchange (0) nor fmi2CoSimulation (1)",
               EMC_MODEL_IDENTIFIER, (int)fmuType);
    if (fmuGUID == NULL || strcmp(fmuGUID, EMC_GUID) != 0)
        REFUSE("%s: fmi2Instantiate: GUID %s does not match the FMU's %s", EMC_MODEL_IDENTIFIER,
               fmuGUID ? fmuGUID : "(null)", EMC_GUID);
    c = (emc_instance *)calloc(1, sizeof *c);    /* the only allocation of an instance's life */
    if (c == NULL)
        REFUSE("%s: fmi2Instantiate: out of memory", EMC_MODEL_IDENTIFIER);
#undef REFUSE
    c->magic = EMC_MAGIC;
    c->interface = fmuType;
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
    if (toleranceDefined && !(isfinite(tolerance) && tolerance > 0.0))
        return fail(c, fmi2Error, "fmi2SetupExperiment: tolerance = %g is not finite and > 0", tolerance);
    if (!isfinite(startTime))
        return fail(c, fmi2Error, "fmi2SetupExperiment: startTime = %g is not finite", startTime);
    if (stopTimeDefined && !(stopTime >= startTime))
        return fail(c, fmi2Error, "fmi2SetupExperiment: stopTime = %g is not >= startTime = %g", stopTime, startTime);
    c->d.time = c->d.start_time = startTime;
    c->d.tolerance_defined = toleranceDefined ? 1 : 0;
    c->d.tolerance = toleranceDefined ? tolerance : 0.0;
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
    if (c->interface == fmi2CoSimulation && !(c->d.rtol >= EMC_RTOL_MIN && c->d.rtol <= EMC_RTOL_MAX))
        return fail(c, fmi2Error, "fmi2ExitInitializationMode: parameter rtol = %g violates 1e-14 <= rtol <= 1e-2 "
                    "(relative tolerance of the plant integration)", c->d.rtol);
    memcpy(c->d.x, c->d.x0, sizeof c->d.x);
    c->d.h_next = 0.0;
    c->d.mode = c->interface == fmi2CoSimulation ? M_STEP : M_EVENT;
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component component)
{
    ENTER("fmi2Terminate", M_EVENT | M_CONTINUOUS | M_STEP);
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
    ENTER("fmi2GetReal", M_INITIALIZATION | M_EVENT | M_CONTINUOUS | M_TERMINATED | M_STEP);
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
    ENTER("fmi2SetReal", M_INSTANTIATED | M_INITIALIZATION | M_EVENT | M_CONTINUOUS | M_STEP);
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
        case EMC_INPUT: c->d.u[v->index] = value[i]; c->d.have_u_end = 0; break;
        default: break;
        }
    }
    return fmi2OK;
}

#define NO_VARIABLES(function, type, constness)                                                       \
    fmi2Status function(fmi2Component component, const fmi2ValueReference vr[], size_t nvr, constness type value[]) \
    {                                                                                                 \
        ENTER(#function, M_ANY);   \
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
    if (s->magic != EMC_STATE_MAGIC || !(s->mode & (M_ANY))
        || (s->mode & (s->mode - 1)))
        return fail(c, fmi2Error, "%s: not an FMU state of %s", function, EMC_MODEL_IDENTIFIER);
    if (!isfinite(s->time) || !all_finite(s->par, EMC_N_PARAMETERS) || !all_finite(s->x0, EMC_N)
        || !isfinite(s->rtol) || !all_finite(s->u, EMC_N_INPUTS) || !isfinite(s->tolerance)
        || !isfinite(s->start_time) || !(isfinite(s->h_next) && s->h_next >= 0.0)
        || !all_finite(s->u_end, 2 * EMC_N_INPUTS) || !all_finite(&s->du[0][0], EMC_MAX_ORDER * EMC_N_INPUTS))
        return fail(c, fmi2Error, "%s: the FMU state holds values that are not finite", function);
    if (s->mode & (M_EVENT | M_CONTINUOUS | M_TERMINATED | M_STEP)) {
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
    ENTER("fmi2GetFMUstate", M_ANY);
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
    ENTER("fmi2SetFMUstate", M_ANY);
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
    ENTER("fmi2FreeFMUstate", M_ANY);
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
    ENTER("fmi2SerializedFMUstateSize", M_ANY);
    if (size == NULL) return fail(c, fmi2Error, "fmi2SerializedFMUstateSize: size is NULL");
    if (pooled(c, FMUstate) == NULL) return fail(c, fmi2Error, "fmi2SerializedFMUstateSize: not an FMU state of this instance");
    *size = EMC_SERIAL_SIZE;
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component component, fmi2FMUstate FMUstate, fmi2Byte serializedState[], size_t size)
{
    emc_data *s;
    ENTER("fmi2SerializeFMUstate", M_ANY);
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
    ENTER("fmi2DeSerializeFMUstate", M_ANY);
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
    ENTER("fmi2GetDirectionalDerivative", M_INITIALIZATION | M_EVENT | M_CONTINUOUS | M_TERMINATED | M_STEP);
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
    ONLY("fmi2EnterEventMode", fmi2ModelExchange);
    c->d.mode = M_EVENT;
    return fmi2OK;
}

fmi2Status fmi2NewDiscreteStates(fmi2Component component, fmi2EventInfo *eventInfo)
{
    char why[200], where[300];
    ENTER("fmi2NewDiscreteStates", M_EVENT);
    ONLY("fmi2NewDiscreteStates", fmi2ModelExchange);
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
    ONLY("fmi2EnterContinuousTimeMode", fmi2ModelExchange);
    c->d.mode = M_CONTINUOUS;
    return fmi2OK;
}

fmi2Status fmi2CompletedIntegratorStep(fmi2Component component, fmi2Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi2Boolean *enterEventMode, fmi2Boolean *terminateSimulation)
{
    ENTER("fmi2CompletedIntegratorStep", M_CONTINUOUS);
    ONLY("fmi2CompletedIntegratorStep", fmi2ModelExchange);
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
    ONLY("fmi2SetTime", fmi2ModelExchange);
    if (!isfinite(time)) return fail(c, fmi2Error, "fmi2SetTime: time = %g is not finite", time);
    c->d.time = time;
    return fmi2OK;
}

fmi2Status fmi2SetContinuousStates(fmi2Component component, const fmi2Real x[], size_t nx)
{
    ENTER("fmi2SetContinuousStates", M_CONTINUOUS);
    ONLY("fmi2SetContinuousStates", fmi2ModelExchange);
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
    ONLY("fmi2GetDerivatives", fmi2ModelExchange);
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
    ONLY("fmi2GetEventIndicators", fmi2ModelExchange);
    if (eventIndicators == NULL || ni != 1)
        return fail(c, fmi2Error, "fmi2GetEventIndicators: %zu values asked for, the FMU has 1 (or NULL)", ni);
    emc_margin(c->d.par, state(c), c->d.u, eventIndicators);
    return fmi2OK;
}

fmi2Status fmi2GetContinuousStates(fmi2Component component, fmi2Real x[], size_t nx)
{
    ENTER("fmi2GetContinuousStates", M_INITIALIZATION | M_EVENT | M_CONTINUOUS | M_TERMINATED);
    ONLY("fmi2GetContinuousStates", fmi2ModelExchange);
    if (x == NULL || nx != EMC_N)
        return fail(c, fmi2Error, "fmi2GetContinuousStates: %zu values asked for, the FMU has %d states (or NULL)", nx, EMC_N);
    memcpy(x, state(c), sizeof c->d.x);
    return fmi2OK;
}

fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component component, fmi2Real x_nominal[], size_t nx)
{
    double out[EMC_N];
    ENTER("fmi2GetNominalsOfContinuousStates", M_INSTANTIATED | M_EVENT | M_CONTINUOUS | M_TERMINATED);
    ONLY("fmi2GetNominalsOfContinuousStates", fmi2ModelExchange);
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

/* ---- Co-Simulation: the integration of components.plant_step.GeneralStepper in C ------------------- */
/* RODAS4 (Hairer & Wanner, Solving ODEs II, Sec. IV.7; rodas.f, METH = 1) in the form
   (I/(h gamma) - J) K_i = f(y + sum_j a_ij K_j, u(t + alpha_i h)) + sum_j (c_ij / h) K_j + gamma_i h f_t,
   y_new = Y_6 + K_6 (stiffly accurate), error estimate K_6; the coefficients of components.plant_step. */
static const double RODAS_GAMMA = 0.25;
static const double RODAS_A[6][5] = {
    {0, 0, 0, 0, 0},
    {1.544, 0, 0, 0, 0},
    {0.9466785280815826, 0.2557011698983284, 0, 0, 0},
    {3.314825187068521, 2.896124015972201, 0.9986419139977817, 0, 0},
    {1.221224509226641, 6.019134481288629, 12.53708332932087, -0.6878860361058950, 0},
    {1.221224509226641, 6.019134481288629, 12.53708332932087, -0.6878860361058950, 1.0}};
static const double RODAS_C[6][5] = {
    {0, 0, 0, 0, 0},
    {-5.6688, 0, 0, 0, 0},
    {-2.430093356833875, -0.2063599157091915, 0, 0, 0},
    {-0.1073529058151375, -9.594562251023355, -20.47028614809616, 0, 0},
    {7.496443313967647, -10.24680431464352, -33.99990352819905, 11.70890893206160, 0},
    {8.083246795921522, -7.981132988064893, -31.52159432874371, 16.31930543123136, -6.058818238834054}};
static const double RODAS_TIME[6] = {0.0, 0.386, 0.21, 0.63, 1.0, 1.0};
static const double RODAS_STAGE_GAMMA[6] = {0.25, -0.1043, 0.1035, -0.0362, 0.0, 0.0};

/* the input polynomial of a step: u_i(tau) = sum_k c_k tau^k / k!, c_0 = u_i, c_k = du[k-1][i] */
typedef struct {
    int order;                               /* the highest order with a coefficient != 0 */
    double c[EMC_MAX_ORDER + 1][EMC_N_INPUTS];
} emc_poly;

/* d^shift/dtau^shift of the polynomial at tau >= 0, every input */
static void poly_value(const emc_poly *P, double tau, int shift, double *out)
{
    int i, k;
    for (i = 0; i < EMC_N_INPUTS; i++) out[i] = 0.0;
    for (k = P->order; k >= shift; k--)       /* Horner: out_k = c_k + out_(k+1) tau / (k + 1 - shift) */
        for (i = 0; i < EMC_N_INPUTS; i++)
            out[i] = P->c[k][i] + out[i] * tau / (double)(k + 1 - shift);
}

/* LU with partial pivoting of the n x n matrix A (in place); 0 if singular */
static int lu_factor(double *A, int *piv)
{
    int i, j, k, n = EMC_N;
    for (k = 0; k < n; k++) {
        int p = k;
        for (i = k + 1; i < n; i++)
            if (fabs(A[i * n + k]) > fabs(A[p * n + k])) p = i;
        piv[k] = p;
        if (!(A[p * n + k] != 0.0) || !isfinite(A[p * n + k])) return 0;
        if (p != k)
            for (j = 0; j < n; j++) { double t = A[k * n + j]; A[k * n + j] = A[p * n + j]; A[p * n + j] = t; }
        for (i = k + 1; i < n; i++) {
            A[i * n + k] /= A[k * n + k];
            for (j = k + 1; j < n; j++) A[i * n + j] -= A[i * n + k] * A[k * n + j];
        }
    }
    return 1;
}

static void lu_solve(const double *A, const int *piv, double *b)
{
    int i, j, n = EMC_N;
    for (i = 0; i < n; i++) {
        double t = b[piv[i]];
        b[piv[i]] = b[i];
        b[i] = t;
        for (j = 0; j < i; j++) b[i] -= A[i * n + j] * b[j];
    }
    for (i = n - 1; i >= 0; i--) {
        for (j = i + 1; j < n; j++) b[i] -= A[i * n + j] * b[j];
        b[i] /= A[i * n + i];
    }
}

/* one RODAS4 substep of size h from the scaled state y at tau = t: y_new and the error estimate; 0 if the
   iteration matrix is singular */
static int rodas4(const double *par, const double *s, const emc_poly *P, const double *y, double t, double h,
                  double *y_new, double *err)
{
    double eta[EMC_N], J[EMC_N * EMC_N], g[EMC_N * EMC_N_INPUTS], du[EMC_N_INPUTS], ui[EMC_N_INPUTS];
    double ft[EMC_N], K[6][EMC_N], Y[EMC_N], f[EMC_N];
    int piv[EMC_N], i, j, k, l;
    const double hi = 1.0 / h, gi = 1.0 / (h * RODAS_GAMMA);
    for (k = 0; k < EMC_N; k++) eta[k] = y[k] * s[k];
    poly_value(P, t, 0, ui);
    emc_jacobian(par, eta, ui, J);           /* J = F hess H, eq. (open-loop elecmech); scaled below */
    for (k = 0; k < EMC_N; k++)
        for (l = 0; l < EMC_N; l++)
            J[k * EMC_N + l] = (k == l ? gi : 0.0) - J[k * EMC_N + l] * s[l] / s[k];
    if (!lu_factor(J, piv)) return 0;
    emc_g(par, eta, ui, g);
    poly_value(P, t, 1, du);                  /* h f_t = h g u'(t), scaled */
    for (k = 0; k < EMC_N; k++) {
        ft[k] = 0.0;
        for (l = 0; l < EMC_N_INPUTS; l++) ft[k] += g[k * EMC_N_INPUTS + l] * du[l];
        ft[k] *= h / s[k];
    }
    for (i = 0; i < 6; i++) {
        for (k = 0; k < EMC_N; k++) {
            Y[k] = y[k];
            for (j = 0; j < i; j++) Y[k] += RODAS_A[i][j] * K[j][k];
            eta[k] = Y[k] * s[k];
        }
        poly_value(P, t + RODAS_TIME[i] * h, 0, ui);
        emc_f(par, eta, ui, f);
        for (k = 0; k < EMC_N; k++) {
            double r = f[k] / s[k] + RODAS_STAGE_GAMMA[i] * ft[k];
            for (j = 0; j < i; j++) r += hi * RODAS_C[i][j] * K[j][k];
            K[i][k] = r;
        }
        lu_solve(J, piv, K[i]);
    }
    for (k = 0; k < EMC_N; k++) {
        y_new[k] = Y[k] + K[5][k];
        err[k] = K[5][k];
    }
    return 1;
}

/* the rtol of doStep: the tighter of the parameter and the master's tolerance (not below 1e-14), as
   fmus/plant.py's integration_tolerance */
static double integration_tolerance(const emc_instance *c)
{
    double tol;
    if (!c->d.tolerance_defined) return c->d.rtol;
    tol = c->d.tolerance > EMC_RTOL_MIN ? c->d.tolerance : EMC_RTOL_MIN;
    return tol < c->d.rtol ? tol : c->d.rtol;
}

/* integrate the step [0, h] from c->d.x; 0 with `why` on failure (the state is kept) */
static int integrate(emc_instance *c, const emc_poly *P, double h, double *x_end, double *h_next, char *why, size_t size)
{
    double s[EMC_N], y[EMC_N], y_new[EMC_N], err[EMC_N], eta[EMC_N];
    const double rtol = integration_tolerance(c), h_min = 1e-13 * h;
    double t = 0.0, hs = (c->d.h_next > 0.0 && c->d.h_next < h) ? c->d.h_next : h;
    int n = 0, k;
    nominals(c->d.par, s);
    for (k = 0; k < EMC_N; k++) y[k] = c->d.x[k] / s[k];
    for (n = 0; n < EMC_MAX_SUBSTEPS; n++) {
        const double remaining = h - t;
        const int last = hs >= remaining * (1.0 - 1e-9);
        const double hh = last ? remaining : hs;
        double e = INFINITY, factor;
        if (rodas4(c->d.par, s, P, y, t, hh, y_new, err)) {
            e = 0.0;
            for (k = 0; k < EMC_N; k++) {
                double scale = rtol * (1.0 + fmax(fabs(y[k]), fabs(y_new[k])));
                e += (err[k] / scale) * (err[k] / scale);
            }
            e = sqrt(e / EMC_N);
        }
        /* components.plant_step.step_factor: 0.9 e^(-1/4) limited to [0.2, 5] */
        if (!isfinite(e)) { e = INFINITY; factor = 0.2; }
        else factor = e > 0.0 ? fmin(5.0, fmax(0.2, 0.9 * pow(e, -0.25))) : 5.0;
        if (e <= 1.0) {
            for (k = 0; k < EMC_N; k++) { y[k] = y_new[k]; eta[k] = y[k] * s[k]; }
            if (domain_problem(c->d.par, eta, why, size)) return 0;
            if (last) {
                for (k = 0; k < EMC_N; k++) x_end[k] = eta[k];
                *h_next = (hh < hs && hh * factor < hs) ? hs : hh * factor;
                return 1;
            }
            t += hh;
            hs = hh * factor;
        } else {
            hs = hh * factor;
            if (hs < h_min) {
                snprintf(why, size, "step size underflow (%.3g s) at t + %.6g s", hs, t);
                return 0;
            }
        }
    }
    snprintf(why, size, "more than %d substeps", EMC_MAX_SUBSTEPS);
    return 0;
}

fmi2Status fmi2DoStep(fmi2Component component, fmi2Real currentCommunicationPoint, fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint)
{
    emc_poly P;
    double x_end[EMC_N], h_next = 0.0, bound = 0.0, term = 1.0, scale;
    char why[200], where[300];
    int i, k;
    ENTER("fmi2DoStep", M_STEP);
    ONLY("fmi2DoStep", fmi2CoSimulation);
    (void)noSetFMUStatePriorToCurrentPoint;
    if (!(isfinite(currentCommunicationPoint) && isfinite(communicationStepSize) && communicationStepSize > 0.0))
        return fail(c, fmi2Error, "fmi2DoStep: currentCommunicationPoint = %g, communicationStepSize = %g: both must be "
                    "finite and the step > 0", currentCommunicationPoint, communicationStepSize);
    scale = fmax(fmax(fabs(c->d.time), fabs(currentCommunicationPoint)), fmax(fabs(c->d.start_time), communicationStepSize));
    if (fabs(currentCommunicationPoint - c->d.time) > EMC_TIME_TOLERANCE * scale)
        return fail(c, fmi2Error, "fmi2DoStep: currentCommunicationPoint = %.17g s is not this FMU's time %.17g s",
                    currentCommunicationPoint, c->d.time);
    memset(&P, 0, sizeof P);
    for (i = 0; i < EMC_N_INPUTS; i++) P.c[0][i] = c->d.u[i];
    for (k = 1; k <= EMC_MAX_ORDER; k++)
        for (i = 0; i < EMC_N_INPUTS; i++) {
            P.c[k][i] = c->d.du[k - 1][i];
            if (P.c[k][i] != 0.0) P.order = k;
        }
    for (k = 0; k <= P.order; k++) {          /* sum_k max_i |c_k| h^k / k! must be finite */
        double m = 0.0;
        if (k > 0) term *= communicationStepSize / k;
        for (i = 0; i < EMC_N_INPUTS; i++) m = fmax(m, fabs(P.c[k][i]));
        bound += m * term;
    }
    if (!isfinite(bound))
        return fail(c, fmi2Discard, "fmi2DoStep at t = %.9g s: the input polynomial overflows over the step h = %g s",
                    c->d.time, communicationStepSize);
    if (!integrate(c, &P, communicationStepSize, x_end, &h_next, why, sizeof why)) {
        format_state(c->d.x, where, sizeof where);
        return fail(c, fmi2Discard, "doStep from t = %.9g s over h = %.6g s from (%s) failed: %s. The state is left "
                    "at t = %.9g s.", c->d.time, communicationStepSize, where, why, c->d.time);
    }
    memcpy(c->d.x, x_end, sizeof x_end);
    c->d.h_next = h_next;
    poly_value(&P, communicationStepSize, 0, c->d.u_end);
    poly_value(&P, communicationStepSize, 1, c->d.u_end + EMC_N_INPUTS);
    c->d.have_u_end = 1;
    memset(c->d.du, 0, sizeof c->d.du);       /* set again by the master for the next step */
    c->d.time = currentCommunicationPoint + communicationStepSize;
    return fmi2OK;
}

fmi2Status fmi2SetRealInputDerivatives(fmi2Component component, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[])
{
    size_t i;
    ENTER("fmi2SetRealInputDerivatives", M_INITIALIZATION | M_STEP);
    ONLY("fmi2SetRealInputDerivatives", fmi2CoSimulation);
    if (check_references(c, "fmi2SetRealInputDerivatives", vr, nvr, value) != fmi2OK) return fmi2Error;
    if (nvr > 0 && order == NULL) return fail(c, fmi2Error, "fmi2SetRealInputDerivatives: order is NULL");
    for (i = 0; i < nvr; i++) {               /* all or nothing */
        const emc_variable *v = &EMC_VARIABLES[vr[i]];
        if (v->kind != EMC_INPUT)
            return fail(c, fmi2Error, "fmi2SetRealInputDerivatives: %s is not a Real input", v->name);
        if (order[i] < 1 || order[i] > EMC_MAX_ORDER)
            return fail(c, fmi2Error, "fmi2SetRealInputDerivatives: order %d for input %s is not in 1..%d", (int)order[i],
                        v->name, EMC_MAX_ORDER);
        if (!isfinite(value[i]))
            return fail(c, fmi2Error, "fmi2SetRealInputDerivatives: derivative of order %d of input %s = %g is not finite",
                        (int)order[i], v->name, value[i]);
    }
    for (i = 0; i < nvr; i++)
        c->d.du[order[i] - 1][EMC_VARIABLES[vr[i]].index] = value[i];
    return fmi2OK;
}

/* d^order/dt^order (1, 2) of q, p, x_e and H: eta' = f(eta, u), eta'' = J eta' + g u',
   H' = grad H . eta', H'' = eta'^T hess H eta' + grad H . eta'' (components.ph_plant.time_derivatives), with
   the input in force: the value and rate at the end of the last step until the master sets u again */
fmi2Status fmi2GetRealOutputDerivatives(fmi2Component component, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[])
{
    double u[EMC_N_INPUTS], du[EMC_N_INPUTS], d1[EMC_N], d2[EMC_N], J[EMC_N * EMC_N], g[EMC_N * EMC_N_INPUTS];
    double gH[EMC_N], hH[EMC_N * EMC_N], H1 = 0.0, H2 = 0.0;
    const double *x;
    size_t i;
    int k, l;
    ENTER("fmi2GetRealOutputDerivatives", M_INITIALIZATION | M_STEP | M_TERMINATED);
    ONLY("fmi2GetRealOutputDerivatives", fmi2CoSimulation);
    if (check_references(c, "fmi2GetRealOutputDerivatives", vr, nvr, value) != fmi2OK) return fmi2Error;
    if (nvr > 0 && order == NULL) return fail(c, fmi2Error, "fmi2GetRealOutputDerivatives: order is NULL");
    for (i = 0; i < nvr; i++) {
        const emc_variable *v = &EMC_VARIABLES[vr[i]];
        if (v->kind != EMC_STATE && v->kind != EMC_ENERGY)
            return fail(c, fmi2Error, "fmi2GetRealOutputDerivatives: %s is not a Real output", v->name);
        if (order[i] < 1 || order[i] > 2)
            return fail(c, fmi2Error, "fmi2GetRealOutputDerivatives: order %d for output %s is not in 1..2", (int)order[i],
                        v->name);
    }
    if ((c->d.mode & M_INITIALIZATION) && check_parameters(c, "fmi2GetRealOutputDerivatives") != fmi2OK)
        return fmi2Error;
    for (l = 0; l < EMC_N_INPUTS; l++) {
        u[l] = c->d.have_u_end ? c->d.u_end[l] : c->d.u[l];
        du[l] = c->d.have_u_end ? c->d.u_end[EMC_N_INPUTS + l] : c->d.du[0][l];
    }
    x = state(c);
    emc_f(c->d.par, x, u, d1);
    emc_jacobian(c->d.par, x, u, J);
    emc_g(c->d.par, x, u, g);
    emc_grad_H(c->d.par, x, u, gH);
    emc_hess_H(c->d.par, x, u, hH);
    for (k = 0; k < EMC_N; k++) {
        d2[k] = 0.0;
        for (l = 0; l < EMC_N; l++) d2[k] += J[k * EMC_N + l] * d1[l];
        for (l = 0; l < EMC_N_INPUTS; l++) d2[k] += g[k * EMC_N_INPUTS + l] * du[l];
    }
    for (k = 0; k < EMC_N; k++) {
        H1 += gH[k] * d1[k];
        H2 += gH[k] * d2[k];
        for (l = 0; l < EMC_N; l++) H2 += d1[k] * hH[k * EMC_N + l] * d1[l];
    }
    for (i = 0; i < nvr; i++) {
        const emc_variable *v = &EMC_VARIABLES[vr[i]];
        if (v->kind == EMC_ENERGY) value[i] = order[i] == 1 ? H1 : H2;
        else value[i] = order[i] == 1 ? d1[v->index] : d2[v->index];
        if (!isfinite(value[i]))
            return fail(c, fmi2Error, "fmi2GetRealOutputDerivatives: d^%d %s/dt^%d is not finite at t = %.9g s",
                        (int)order[i], v->name, (int)order[i], c->d.time);
    }
    return fmi2OK;
}

fmi2Status fmi2CancelStep(fmi2Component component)
{
    ENTER("fmi2CancelStep", M_STEP);
    return fail(c, fmi2Error, "fmi2CancelStep: doStep never runs asynchronously here; there is nothing to cancel");
}

#define STATUS(function, type)                                                                        \
    fmi2Status function(fmi2Component component, const fmi2StatusKind s, type *value)                 \
    {                                                                                                 \
        ENTER(#function, M_STEP | M_TERMINATED);                                                      \
        ONLY(#function, fmi2CoSimulation);                                                            \
        (void)s;                                                                                      \
        (void)value;                                                                                  \
        return fail(c, fmi2Discard, "%s: doStep never runs asynchronously here (no status to ask)", #function); \
    }
STATUS(fmi2GetStatus, fmi2Status)
STATUS(fmi2GetIntegerStatus, fmi2Integer)
STATUS(fmi2GetStringStatus, fmi2String)

/* fmi2LastSuccessfulTime: the FMU's time (the end of its last successful step) */
fmi2Status fmi2GetRealStatus(fmi2Component component, const fmi2StatusKind s, fmi2Real *value)
{
    ENTER("fmi2GetRealStatus", M_STEP | M_TERMINATED);
    ONLY("fmi2GetRealStatus", fmi2CoSimulation);
    if (value == NULL) return fail(c, fmi2Error, "fmi2GetRealStatus: value is NULL");
    if (s != fmi2LastSuccessfulTime)
        return fail(c, fmi2Discard, "fmi2GetRealStatus: status kind %d is not provided (fmi2LastSuccessfulTime is)", (int)s);
    *value = c->d.time;
    return fmi2OK;
}

/* fmi2Terminated: false (the FMU never asks to end the simulation after a step it discarded) */
fmi2Status fmi2GetBooleanStatus(fmi2Component component, const fmi2StatusKind s, fmi2Boolean *value)
{
    ENTER("fmi2GetBooleanStatus", M_STEP | M_TERMINATED);
    ONLY("fmi2GetBooleanStatus", fmi2CoSimulation);
    if (value == NULL) return fail(c, fmi2Error, "fmi2GetBooleanStatus: value is NULL");
    if (s != fmi2Terminated)
        return fail(c, fmi2Discard, "fmi2GetBooleanStatus: status kind %d is not provided (fmi2Terminated is)", (int)s);
    *value = fmi2False;
    return fmi2OK;
}
