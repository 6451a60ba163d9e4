/* emcosim's native Reference FMU: the reference generators of components/references.py in C (ME and CS,
 * no states; the outputs are functions of time alone).
 *
 * kind 0 constant q* = q_d; 1 sinusoid q* = offset + amplitude sin(omega t + phase) (eq. csim for the MEMS);
 * 2 smooth_step from q_from to q_to over [t_start, t_start + duration] with s(tau) = 35 tau^4 - 84 tau^5
 * + 70 tau^6 - 20 tau^7 (derivatives of order >= 4 from the right). Outputs: the jet (q*, q*', q*'', q*''');
 * fmi2GetRealOutputDerivatives of output k0 (q*^(k0)) of order k is q*^(k0 + k), k <= 3.
 * The formulas are components.references' (Constant, Sinusoid, SmoothStep.derivatives), written again here:
 * tests/test_native_fmus.py pins them to the Python at random times and parameters.
 *
 * The same rules as emc_fmi2.c: every argument checked before it is read, calls outside the state machine
 * refused with fmi2Error and one log line, the chosen kind's parameters checked (components.parameters),
 * memory allocated in fmi2Instantiate only, FMU states from a fixed pool.
 */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "emc_reference.h"

#define EMC_MAGIC 0x656d6372u              /* "emcr": a live reference instance */
#define EMC_STATE_MAGIC 0x656d7273u
#define EMC_STATE_POOL 8
#define EMC_MESSAGE 512
#define EMC_TIME_TOLERANCE 1e-12           /* fmus/slave.py: COMMUNICATION_POINT_TOLERANCE */
#define EMC_MAX_ORDER 6                    /* q*''' of order 3 */

typedef enum {
    M_INSTANTIATED = 1 << 0, M_INITIALIZATION = 1 << 1, M_EVENT = 1 << 2, M_CONTINUOUS = 1 << 3,
    M_TERMINATED = 1 << 4, M_STEP = 1 << 6
} emc_mode;
#define M_ANY (M_INSTANTIATED | M_INITIALIZATION | M_EVENT | M_CONTINUOUS | M_TERMINATED | M_STEP)
#define M_INITIALIZED (M_EVENT | M_CONTINUOUS | M_TERMINATED | M_STEP)

typedef struct {
    unsigned magic;
    int mode;
    int in_use;
    int kind;
    double time;
    double start_time;
    double par[EMC_N_PARAMETERS];
} emc_data;

typedef struct {
    unsigned magic;
    fmi2Type interface;
    fmi2CallbackFunctions functions;
    char name[128];
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

static fmi2Status fail(emc_instance *c, fmi2Status status, const char *format, ...)
{
    char text[EMC_MESSAGE];
    va_list args;
    if (c->functions.logger == NULL) return status;
    va_start(args, format);
    vsnprintf(text, sizeof text, format, args);
    va_end(args);
    c->functions.logger(c->functions.componentEnvironment, c->name, status,
                        status == fmi2Discard ? "logStatusDiscard" : "logStatusError", "%s: %s", EMC_MODEL_IDENTIFIER, text);
    return status;
}

static emc_instance *instance(fmi2Component component)
{
    emc_instance *c = (emc_instance *)component;
    return (c != NULL && c->magic == EMC_MAGIC) ? c : NULL;
}

static fmi2Status allowed(emc_instance *c, const char *function, int mask)
{
    if (c->d.mode & mask) return fmi2OK;
    return fail(c, fmi2Error, "%s is not allowed %s", function, mode_name(c->d.mode));
}

#define ENTER(function, mask)                                      \
    emc_instance *c = instance(component);                         \
    if (c == NULL) return fmi2Error;                               \
    if (allowed(c, function, mask) != fmi2OK) return fmi2Error

#define ONLY(function, kind)                                                                       \
    if (c->interface != kind)                                                                      \
        return fail(c, fmi2Error, "%s is not a function of %s", function,                          \
                    c->interface == fmi2ModelExchange ? "Model Exchange" : "Co-Simulation")

/* kind in {0, 1, 2} and the chosen generator's parameters (components.parameters.Parameter.check) */
static fmi2Status check_parameters(emc_instance *c, const char *function, const emc_data *d)
{
    int i;
    if (d->kind < 0 || d->kind > 2)
        return fail(c, fmi2Error, "%s: parameter kind = %d violates kind in {0, 1, 2} (0 constant, 1 sinusoid, "
                    "2 smooth_step)", function, d->kind);
    for (i = 0; i < EMC_N_PARAMETERS; i++) {
        double x = d->par[i];
        const char *cond = EMC_PARAMETER_CONDITIONS[i];
        int ok = isfinite(x) && (x == 0.0 || (fabs(x) >= 1e-100 && fabs(x) <= 1e100));
        if (strcmp(cond, "> 0") == 0) ok = ok && x > 0.0;
        if (strcmp(cond, ">= 0") == 0) ok = ok && x >= 0.0;
        if (EMC_PARAMETER_KIND[i] == d->kind && !ok)
            return fail(c, fmi2Error, "%s: parameter %s = %.17g violates %s %s (finite, 1e-100 <= |value| <= 1e100 "
                        "unless 0)", function, EMC_PARAMETER_NAMES[i], x, EMC_PARAMETER_NAMES[i], cond);
    }
    return fmi2OK;
}

/* (q*, q*', ..., q*^(order)) at time t: components.references' derivatives */
static void derivatives(const emc_data *d, double t, int order, double *out)
{
    int k, n;
    const double *p = d->par;
    for (k = 0; k <= order; k++) out[k] = 0.0;
    if (d->kind == 0) {
        out[0] = p[EMC_P_q_d];
    } else if (d->kind == 1) {                 /* amplitude omega^k sin(omega t + phase + k pi/2) */
        const double a = p[EMC_P_amplitude], w = p[EMC_P_omega], th = w * t + p[EMC_P_phase];
        const double s = sin(th), co = cos(th), cycle[4] = {s, co, -s, -co};
        for (k = 0; k <= order; k++)
            out[k] = (k == 0 ? p[EMC_P_offset] : 0.0) + a * pow(w, (double)k) * cycle[k % 4];
    } else {                                   /* (q_to - q_from) s^(k)(tau) / duration^k */
        static const double S[8] = {0.0, 0.0, 0.0, 0.0, 35.0, -84.0, 70.0, -20.0};
        const double T = p[EMC_P_duration], tau = (t - p[EMC_P_t_start]) / T;
        const double dq = p[EMC_P_q_to] - p[EMC_P_q_from];
        if (!(tau >= 0.0 && tau < 1.0)) {
            out[0] = tau >= 1.0 ? p[EMC_P_q_to] : p[EMC_P_q_from];
            return;
        }
        for (k = 0; k <= order; k++) {
            double sk = 0.0;
            for (n = k > 4 ? k : 4; n <= 7; n++) {
                double perm = 1.0;             /* n! / (n - k)! */
                int j;
                for (j = 0; j < k; j++) perm *= (double)(n - j);
                sk += S[n] * perm * pow(tau, (double)(n - k));
            }
            out[k] = (k == 0 ? p[EMC_P_q_from] : 0.0) + dq * sk / pow(T, (double)k);
        }
    }
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
    (void)loggingOn;
    if (nCategories > 0 && categories == NULL)
        return fail(c, fmi2Error, "fmi2SetDebugLogging: categories is NULL with nCategories = %zu", nCategories);
    for (i = 0; i < nCategories; i++)
        if (categories[i] == NULL) return fail(c, fmi2Error, "fmi2SetDebugLogging: category %zu is NULL", i);
    return fmi2OK;
}

static void reset_data(emc_data *d)
{
    memset(d, 0, sizeof *d);
    d->magic = EMC_STATE_MAGIC;
    d->mode = M_INSTANTIATED;
    d->kind = EMC_KIND_START;
    memcpy(d->par, EMC_PARAMETER_START, sizeof d->par);
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
    (void)loggingOn;
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
    if (c == NULL) REFUSE("%s: fmi2Instantiate: out of memory", EMC_MODEL_IDENTIFIER);
#undef REFUSE
    c->magic = EMC_MAGIC;
    c->interface = fmuType;
    c->functions = *functions;
    snprintf(c->name, sizeof c->name, "%s", instanceName);
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
    if (!isfinite(startTime)) return fail(c, fmi2Error, "fmi2SetupExperiment: startTime = %g is not finite", startTime);
    if (stopTimeDefined && !(stopTime >= startTime))
        return fail(c, fmi2Error, "fmi2SetupExperiment: stopTime = %g is not >= startTime = %g", stopTime, startTime);
    c->d.time = c->d.start_time = startTime;
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
    ENTER("fmi2ExitInitializationMode", M_INITIALIZATION);
    if (check_parameters(c, "fmi2ExitInitializationMode", &c->d) != fmi2OK) return fmi2Error;
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
    if (vr == NULL || value == NULL) return fail(c, fmi2Error, "%s: vr or value is NULL with nvr = %zu", function, nvr);
    for (i = 0; i < nvr; i++)
        if (vr[i] >= EMC_N_VARIABLES)
            return fail(c, fmi2Error, "%s: value reference %u does not exist (0 to %d)", function, vr[i], EMC_N_VARIABLES - 1);
    return fmi2OK;
}

fmi2Status fmi2GetReal(fmi2Component component, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[])
{
    double jet[4];
    size_t i;
    int have = 0;
    ENTER("fmi2GetReal", M_INITIALIZATION | M_INITIALIZED);
    if (check_references(c, "fmi2GetReal", vr, nvr, value) != fmi2OK) return fmi2Error;
    for (i = 0; i < nvr; i++) {
        const emc_r_variable *v = &EMC_VARIABLES[vr[i]];
        switch (v->kind) {
        case EMC_R_PARAMETER: value[i] = c->d.par[v->index]; break;
        case EMC_R_TIME: value[i] = c->d.time; break;
        case EMC_R_OUTPUT:
            if (!have) {
                if (!(c->d.mode & M_INITIALIZED) && check_parameters(c, "fmi2GetReal", &c->d) != fmi2OK) return fmi2Error;
                derivatives(&c->d, c->d.time, 3, jet);
                have = 1;
            }
            value[i] = jet[v->index];
            if (!isfinite(value[i]))
                return fail(c, fmi2Error, "fmi2GetReal: %s is not finite at t = %.9g s", v->name, c->d.time);
            break;
        default: return fail(c, fmi2Error, "fmi2GetReal: %s is an Integer variable", v->name);
        }
    }
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component component, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[])
{
    size_t i;
    /* allowed wherever FMI 2.0 allows fmi2SetReal (a host may set no variable, nvr = 0, in any such mode);
       the parameters only before fmi2ExitInitializationMode, as emc_fmi2.c */
    ENTER("fmi2SetReal", M_INSTANTIATED | M_INITIALIZATION | M_EVENT | M_CONTINUOUS | M_STEP);
    if (check_references(c, "fmi2SetReal", vr, nvr, value) != fmi2OK) return fmi2Error;
    for (i = 0; i < nvr; i++) {
        const emc_r_variable *v = &EMC_VARIABLES[vr[i]];
        if (v->kind != EMC_R_PARAMETER) return fail(c, fmi2Error, "fmi2SetReal: %s cannot be set", v->name);
        if (!(c->d.mode & (M_INSTANTIATED | M_INITIALIZATION)))
            return fail(c, fmi2Error, "fmi2SetReal: the parameter %s cannot be set %s", v->name, mode_name(c->d.mode));
        if (!isfinite(value[i])) return fail(c, fmi2Error, "fmi2SetReal: %s = %g is not finite", v->name, value[i]);
    }
    for (i = 0; i < nvr; i++) c->d.par[EMC_VARIABLES[vr[i]].index] = value[i];
    return fmi2OK;
}

fmi2Status fmi2GetInteger(fmi2Component component, const fmi2ValueReference vr[], size_t nvr, fmi2Integer value[])
{
    size_t i;
    ENTER("fmi2GetInteger", M_ANY);
    if (check_references(c, "fmi2GetInteger", vr, nvr, value) != fmi2OK) return fmi2Error;
    for (i = 0; i < nvr; i++) {
        if (EMC_VARIABLES[vr[i]].kind != EMC_R_KIND)
            return fail(c, fmi2Error, "fmi2GetInteger: %s is a Real variable", EMC_VARIABLES[vr[i]].name);
        value[i] = c->d.kind;
    }
    return fmi2OK;
}

fmi2Status fmi2SetInteger(fmi2Component component, const fmi2ValueReference vr[], size_t nvr, const fmi2Integer value[])
{
    size_t i;
    ENTER("fmi2SetInteger", M_INSTANTIATED | M_INITIALIZATION | M_EVENT | M_CONTINUOUS | M_STEP);   /* as fmi2SetReal */
    if (check_references(c, "fmi2SetInteger", vr, nvr, value) != fmi2OK) return fmi2Error;
    for (i = 0; i < nvr; i++) {
        if (EMC_VARIABLES[vr[i]].kind != EMC_R_KIND)
            return fail(c, fmi2Error, "fmi2SetInteger: %s is a Real variable", EMC_VARIABLES[vr[i]].name);
        if (!(c->d.mode & (M_INSTANTIATED | M_INITIALIZATION)))
            return fail(c, fmi2Error, "fmi2SetInteger: the parameter %s cannot be set %s", EMC_VARIABLES[vr[i]].name,
                        mode_name(c->d.mode));
    }
    for (i = 0; i < nvr; i++) c->d.kind = value[i];
    return fmi2OK;
}

#define NO_VARIABLES(function, type, constness)                                                       \
    fmi2Status function(fmi2Component component, const fmi2ValueReference vr[], size_t nvr, constness type value[]) \
    {                                                                                                 \
        ENTER(#function, M_ANY);                                                                      \
        (void)value;                                                                                  \
        if (nvr == 0) return fmi2OK;                                                                  \
        if (vr == NULL) return fail(c, fmi2Error, "%s: vr is NULL with nvr = %zu", #function, nvr);   \
        return fail(c, fmi2Error, "%s: value reference %u is not of this type", #function, vr[0]);    \
    }
NO_VARIABLES(fmi2GetBoolean, fmi2Boolean, )
NO_VARIABLES(fmi2GetString, fmi2String, )
NO_VARIABLES(fmi2SetBoolean, fmi2Boolean, const)
NO_VARIABLES(fmi2SetString, fmi2String, const)

/* ---- FMU state ------------------------------------------------------------------------------------ */
static emc_data *pooled(emc_instance *c, fmi2FMUstate s)
{
    int i;
    for (i = 0; i < EMC_STATE_POOL; i++)
        if (s == (fmi2FMUstate)&c->pool[i] && c->pool[i].in_use) return &c->pool[i];
    return NULL;
}

static emc_data *free_slot(emc_instance *c, fmi2FMUstate current)
{
    int i;
    if (current != NULL) return pooled(c, current);
    for (i = 0; i < EMC_STATE_POOL; i++)
        if (!c->pool[i].in_use) return &c->pool[i];
    return NULL;
}

static fmi2Status check_saved(emc_instance *c, const char *function, const emc_data *s)
{
    int i;
    if (s->magic != EMC_STATE_MAGIC || !(s->mode & M_ANY) || (s->mode & (s->mode - 1))
        || ((s->mode & (M_EVENT | M_CONTINUOUS)) && c->interface != fmi2ModelExchange)
        || ((s->mode & M_STEP) && c->interface != fmi2CoSimulation))
        return fail(c, fmi2Error, "%s: not an FMU state of %s", function, EMC_MODEL_IDENTIFIER);
    if (!isfinite(s->time) || !isfinite(s->start_time))
        return fail(c, fmi2Error, "%s: the FMU state holds values that are not finite", function);
    for (i = 0; i < EMC_N_PARAMETERS; i++)
        if (!isfinite(s->par[i])) return fail(c, fmi2Error, "%s: the FMU state holds values that are not finite", function);
    if ((s->mode & M_INITIALIZED) && check_parameters(c, function, s) != fmi2OK) return fmi2Error;
    return fmi2OK;
}

fmi2Status fmi2GetFMUstate(fmi2Component component, fmi2FMUstate *FMUstate)
{
    emc_data *slot;
    ENTER("fmi2GetFMUstate", M_ANY);
    if (FMUstate == NULL) return fail(c, fmi2Error, "fmi2GetFMUstate: FMUstate is NULL");
    slot = free_slot(c, *FMUstate);
    if (slot == NULL) return fail(c, fmi2Error, "fmi2GetFMUstate: no free FMU state (%d at most)", EMC_STATE_POOL);
    *slot = c->d;
    slot->in_use = 1;
    *FMUstate = (fmi2FMUstate)slot;
    return fmi2OK;
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

#define EMC_SERIAL_SIZE (sizeof(EMC_GUID) + sizeof(emc_data))

fmi2Status fmi2SerializedFMUstateSize(fmi2Component component, fmi2FMUstate FMUstate, size_t *size)
{
    ENTER("fmi2SerializedFMUstateSize", M_ANY);
    if (size == NULL || pooled(c, FMUstate) == NULL)
        return fail(c, fmi2Error, "fmi2SerializedFMUstateSize: size is NULL or not an FMU state of this instance");
    *size = EMC_SERIAL_SIZE;
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component component, fmi2FMUstate FMUstate, fmi2Byte serializedState[], size_t size)
{
    emc_data *s;
    ENTER("fmi2SerializeFMUstate", M_ANY);
    s = pooled(c, FMUstate);
    if (s == NULL || serializedState == NULL || size != EMC_SERIAL_SIZE)
        return fail(c, fmi2Error, "fmi2SerializeFMUstate: not an FMU state of this instance, or not a buffer of %zu bytes",
                    (size_t)EMC_SERIAL_SIZE);
    memcpy(serializedState, EMC_GUID, sizeof(EMC_GUID));
    memcpy(serializedState + sizeof(EMC_GUID), s, sizeof *s);
    return fmi2OK;
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component component, const fmi2Byte serializedState[], size_t size,
                                   fmi2FMUstate *FMUstate)
{
    emc_data d, *slot;
    ENTER("fmi2DeSerializeFMUstate", M_ANY);
    if (serializedState == NULL || FMUstate == NULL)
        return fail(c, fmi2Error, "fmi2DeSerializeFMUstate: serializedState or FMUstate is NULL");
    if (size != EMC_SERIAL_SIZE || memcmp(serializedState, EMC_GUID, sizeof(EMC_GUID)) != 0)
        return fail(c, fmi2Error, "fmi2DeSerializeFMUstate: not a serialized FMU state of this FMU (%zu bytes)", size);
    memcpy(&d, serializedState + sizeof(EMC_GUID), sizeof d);
    if (check_saved(c, "fmi2DeSerializeFMUstate", &d) != fmi2OK) return fmi2Error;
    slot = free_slot(c, *FMUstate);
    if (slot == NULL) return fail(c, fmi2Error, "fmi2DeSerializeFMUstate: no free FMU state");
    *slot = d;
    slot->in_use = 1;
    *FMUstate = (fmi2FMUstate)slot;
    return fmi2OK;
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component component, const fmi2ValueReference vUnknown_ref[], size_t nUnknown,
                                        const fmi2ValueReference vKnown_ref[], size_t nKnown,
                                        const fmi2Real dvKnown[], fmi2Real dvUnknown[])
{
    ENTER("fmi2GetDirectionalDerivative", M_ANY);
    (void)vUnknown_ref; (void)nUnknown; (void)vKnown_ref; (void)nKnown; (void)dvKnown; (void)dvUnknown;
    return fail(c, fmi2Error, "fmi2GetDirectionalDerivative: not provided (providesDirectionalDerivative = false; "
                "the outputs depend on no input)");
}

/* ---- Co-Simulation -------------------------------------------------------------------------------- */
fmi2Status fmi2SetRealInputDerivatives(fmi2Component component, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[])
{
    ENTER("fmi2SetRealInputDerivatives", M_ANY);
    (void)vr; (void)order; (void)value;
    if (nvr == 0) return fmi2OK;
    return fail(c, fmi2Error, "fmi2SetRealInputDerivatives: the Reference has no inputs (canInterpolateInputs = false)");
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component component, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[])
{
    double all[EMC_MAX_ORDER + 1];
    size_t i;
    ENTER("fmi2GetRealOutputDerivatives", M_INITIALIZATION | M_STEP | M_TERMINATED);
    ONLY("fmi2GetRealOutputDerivatives", fmi2CoSimulation);
    if (check_references(c, "fmi2GetRealOutputDerivatives", vr, nvr, value) != fmi2OK) return fmi2Error;
    if (nvr > 0 && order == NULL) return fail(c, fmi2Error, "fmi2GetRealOutputDerivatives: order is NULL");
    for (i = 0; i < nvr; i++) {
        if (EMC_VARIABLES[vr[i]].kind != EMC_R_OUTPUT)
            return fail(c, fmi2Error, "fmi2GetRealOutputDerivatives: %s is not a Real output", EMC_VARIABLES[vr[i]].name);
        if (order[i] < 1 || order[i] > 3)
            return fail(c, fmi2Error, "fmi2GetRealOutputDerivatives: order %d for output %s is not in 1..3", (int)order[i],
                        EMC_VARIABLES[vr[i]].name);
    }
    if (nvr == 0) return fmi2OK;
    if ((c->d.mode & M_INITIALIZATION) && check_parameters(c, "fmi2GetRealOutputDerivatives", &c->d) != fmi2OK)
        return fmi2Error;
    derivatives(&c->d, c->d.time, EMC_MAX_ORDER, all);
    for (i = 0; i < nvr; i++) {
        value[i] = all[EMC_VARIABLES[vr[i]].index + order[i]];
        if (!isfinite(value[i]))
            return fail(c, fmi2Error, "fmi2GetRealOutputDerivatives: not finite at t = %.9g s", c->d.time);
    }
    return fmi2OK;
}

fmi2Status fmi2DoStep(fmi2Component component, fmi2Real currentCommunicationPoint, fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint)
{
    double scale;
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
    c->d.time = currentCommunicationPoint + communicationStepSize;
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

/* ---- Model Exchange: no continuous states, no event indicators ----------------------------------- */
fmi2Status fmi2EnterEventMode(fmi2Component component)
{
    ENTER("fmi2EnterEventMode", M_EVENT | M_CONTINUOUS);
    ONLY("fmi2EnterEventMode", fmi2ModelExchange);
    c->d.mode = M_EVENT;
    return fmi2OK;
}

fmi2Status fmi2NewDiscreteStates(fmi2Component component, fmi2EventInfo *eventInfo)
{
    ENTER("fmi2NewDiscreteStates", M_EVENT);
    ONLY("fmi2NewDiscreteStates", fmi2ModelExchange);
    if (eventInfo == NULL) return fail(c, fmi2Error, "fmi2NewDiscreteStates: eventInfo is NULL");
    memset(eventInfo, 0, sizeof *eventInfo);
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

#define NO_STATES(function, mask, constness)                                                          \
    fmi2Status function(fmi2Component component, constness fmi2Real x[], size_t nx)                   \
    {                                                                                                 \
        ENTER(#function, mask);                                                                       \
        ONLY(#function, fmi2ModelExchange);                                                           \
        (void)x;                                                                                      \
        if (nx != 0) return fail(c, fmi2Error, "%s: %zu values for 0 (the Reference has no states)", #function, nx); \
        return fmi2OK;                                                                                \
    }
NO_STATES(fmi2SetContinuousStates, M_CONTINUOUS, const)
NO_STATES(fmi2GetDerivatives, M_EVENT | M_CONTINUOUS | M_TERMINATED, )
NO_STATES(fmi2GetEventIndicators, M_INITIALIZATION | M_INITIALIZED, )
NO_STATES(fmi2GetContinuousStates, M_INITIALIZATION | M_INITIALIZED, )
NO_STATES(fmi2GetNominalsOfContinuousStates, M_INSTANTIATED | M_EVENT | M_CONTINUOUS | M_TERMINATED, )
