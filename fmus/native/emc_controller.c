/* emcosim's FMI 2.0 framework in C: the FMI functions of a native controller FMU (ME and CS, no states).
 *
 * The model (emc_controller.h) supplies the law u(inputs) of components.laws (EMC_N_OUTPUTS entries, any n_e) and
 * its Jacobian, with the feasible reference of Definition 1 and the design's checks; this file
 * supplies the state machines of FMI 2.0 section 3.2.3 (ME) and 4.2.4 (CS), get/set by value reference,
 * the FMU state, du/dt (fmi2GetRealOutputDerivatives, order 1, from the input derivatives the master set:
 * orders >= 2 are accepted and dropped, as the twin's orderUsed = 1), the directional derivatives, and
 * logging. u depends on the inputs only (direct feedthrough): it is computed when read; doStep only checks
 * that it can be computed (fmi2Discard otherwise).
 *
 * The same rules as emc_fmi2.c: every argument checked before it is read; calls outside the state machine
 * refused with fmi2Error and one log line; a u that cannot be computed (a reference that is not feasible,
 * Definition 1: q* outside the domain, no real x_e*, Newton's method failing; a u that is not finite) is answered
 * with fmi2Error (fmi2Discard in doStep) and one log line, never with NaN; memory is allocated in fmi2Instantiate only.
 * strict = 1 (the twin's design checks, components.certificates.design_checks) is not provided: it is
 * refused at fmi2ExitInitializationMode.
 */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "emc_controller.h"

#define EMC_NI EMC_N_CONTROLLER_INPUTS
#define EMC_MAGIC 0x656d6363u              /* "emcc": a live controller instance */
#define EMC_STATE_MAGIC 0x656d6373u        /* "emcs": a saved controller state */
#define EMC_STATE_POOL 8
#define EMC_MESSAGE 512
#define EMC_TIME_TOLERANCE 1e-12           /* fmus/slave.py: COMMUNICATION_POINT_TOLERANCE */

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
    int strict;
    double time;
    double start_time;
    double par[EMC_N_PARAMETERS];
    double gain[EMC_N_GAINS];
    double in[EMC_NI];
    double rate[EMC_NI];                   /* d in / dt the master set for this communication point */
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

static fmi2Status fail(emc_instance *c, fmi2Status status, const char *format, ...)
{
    char text[EMC_MESSAGE];
    va_list args;
    if (c->functions.logger == NULL) return status;
    va_start(args, format);
    vsnprintf(text, sizeof text, format, args);
    va_end(args);
    c->functions.logger(c->functions.componentEnvironment, c->name, status,
                        status == fmi2Discard ? "logStatusDiscard" : "logStatusError", "%s: %s",
                        EMC_MODEL_IDENTIFIER, text);
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

static int all_finite(const double *v, size_t n)
{
    size_t i;
    for (i = 0; i < n; i++)
        if (!isfinite(v[i])) return 0;
    return 1;
}

/* the parameters' and gains' conditions and the controller's construction checks (emc_ctrl_check:
   components.closed_loop); for regulation, the constant reference's feasibility */
static fmi2Status check_design(emc_instance *c, const char *function, const emc_data *d)
{
    double u[EMC_N_OUTPUTS];
    char why[EMC_MESSAGE / 2];
    const char *reason;
    int bad = emc_check_parameters(d->par);
    if (bad >= 0)
        return fail(c, fmi2Error, "%s: parameter %s = %.17g violates %s %s (finite, 1e-100 <= |value| <= 1e100 unless 0)",
                    function, EMC_PARAMETER_NAMES[bad], d->par[bad], EMC_PARAMETER_NAMES[bad], EMC_PARAMETER_CONDITIONS[bad]);
    bad = emc_check_gains(d->gain);
    if (bad >= 0)
        return fail(c, fmi2Error, "%s: parameter %s = %.17g violates %s %s (finite, 1e-100 <= |value| <= 1e100 unless 0)",
                    function, EMC_GAIN_NAMES[bad], d->gain[bad], EMC_GAIN_NAMES[bad], EMC_GAIN_CONDITIONS[bad]);
    if (emc_ctrl_check(d->par, d->gain, why, sizeof why) != 0) return fail(c, fmi2Error, "%s: %s", function, why);
    if (!EMC_TRACKING && (reason = emc_ctrl_law(d->par, d->gain, d->in, u, NULL)) != NULL)
        return fail(c, fmi2Error, "%s: the set point q_d is not feasible (Definition 1: %s)", function, reason);
    return fmi2OK;
}

/* u (EMC_N_OUTPUTS) and, if du is not NULL, du/d inputs at the current inputs: fmi2OK, or `status` with one log
   line (never NaN) */
static fmi2Status compute_u(emc_instance *c, const char *function, fmi2Status status, double *u, double *du)
{
    const char *reason;
    int i;
    for (i = 0; i < EMC_NI; i++)
        if (!isfinite(c->d.in[i]))
            return fail(c, status, "%s: input %s = %g is not finite", function, EMC_INPUT_NAMES[i], c->d.in[i]);
    if (!(c->d.mode & M_INITIALIZED) && check_design(c, function, &c->d) != fmi2OK)
        return status;
    reason = emc_ctrl_law(c->d.par, c->d.gain, c->d.in, u, du);
    if (reason != NULL)
        return fail(c, status, "%s at t = %.9g s: the reference is not feasible (Definition 1: %s)", function, c->d.time,
                    reason);
    for (i = 0; i < EMC_N_OUTPUTS; i++)
        if (!isfinite(u[i]))
            return fail(c, status, "%s at t = %.9g s: u = %g is not finite for these inputs", function, c->d.time, u[i]);
    return fmi2OK;
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
    for (i = 0; i < nCategories; i++)
        if (categories[i] == NULL) return fail(c, fmi2Error, "fmi2SetDebugLogging: category %zu is NULL", i);
    c->logging = loggingOn ? 1 : 0;
    return fmi2OK;
}

static void reset_data(emc_data *d)
{
    memset(d, 0, sizeof *d);
    d->magic = EMC_STATE_MAGIC;
    d->mode = M_INSTANTIATED;
    memcpy(d->par, EMC_PARAMETER_START, sizeof d->par);
    memcpy(d->gain, EMC_GAIN_START, sizeof d->gain);
    memcpy(d->in, EMC_INPUT_START, sizeof d->in);
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
    if (c == NULL) REFUSE("%s: fmi2Instantiate: out of memory", EMC_MODEL_IDENTIFIER);
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
    if (c->d.strict != 0 && c->d.strict != 1)
        return fail(c, fmi2Error, "fmi2ExitInitializationMode: parameter strict = %d violates strict in {0, 1}", c->d.strict);
    if (c->d.strict == 1)
        return fail(c, fmi2Error, "fmi2ExitInitializationMode: strict = 1 (the design checks of "
                    "components.certificates) is not provided by the native controller; use its pythonfmu twin");
    if (check_design(c, "fmi2ExitInitializationMode", &c->d) != fmi2OK) return fmi2Error;
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
            return fail(c, fmi2Error, "%s: value reference %u does not exist (0 to %d)", function, vr[i], EMC_N_VARIABLES - 1);
    return fmi2OK;
}

fmi2Status fmi2GetReal(fmi2Component component, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[])
{
    size_t i;
    double u[EMC_N_OUTPUTS];
    int computed = 0;
    ENTER("fmi2GetReal", M_INITIALIZATION | M_INITIALIZED);
    if (check_references(c, "fmi2GetReal", vr, nvr, value) != fmi2OK) return fmi2Error;
    for (i = 0; i < nvr; i++) {
        const emc_c_variable *v = &EMC_VARIABLES[vr[i]];
        switch (v->kind) {
        case EMC_C_PARAMETER: value[i] = c->d.par[v->index]; break;
        case EMC_C_GAIN: value[i] = c->d.gain[v->index]; break;
        case EMC_C_INPUT: value[i] = c->d.in[v->index]; break;
        case EMC_C_OUTPUT:
            if (!computed && compute_u(c, "fmi2GetReal", fmi2Error, u, NULL) != fmi2OK) return fmi2Error;
            computed = 1;
            value[i] = u[v->index];
            break;
        default:
            return fail(c, fmi2Error, "fmi2GetReal: %s is an Integer variable", v->name);
        }
    }
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component component, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[])
{
    size_t i;
    ENTER("fmi2SetReal", M_INSTANTIATED | M_INITIALIZATION | M_EVENT | M_CONTINUOUS | M_STEP);
    if (check_references(c, "fmi2SetReal", vr, nvr, value) != fmi2OK) return fmi2Error;
    for (i = 0; i < nvr; i++) {           /* all checked before any is set */
        const emc_c_variable *v = &EMC_VARIABLES[vr[i]];
        if (v->kind == EMC_C_OUTPUT) return fail(c, fmi2Error, "fmi2SetReal: %s is an output and cannot be set", v->name);
        if (v->kind == EMC_C_STRICT) return fail(c, fmi2Error, "fmi2SetReal: %s is an Integer variable", v->name);
        if (v->kind != EMC_C_INPUT && !(c->d.mode & (M_INSTANTIATED | M_INITIALIZATION)))
            return fail(c, fmi2Error, "fmi2SetReal: the parameter %s cannot be set %s", v->name, mode_name(c->d.mode));
        if (!isfinite(value[i])) return fail(c, fmi2Error, "fmi2SetReal: %s = %g is not finite", v->name, value[i]);
    }
    for (i = 0; i < nvr; i++) {
        const emc_c_variable *v = &EMC_VARIABLES[vr[i]];
        if (v->kind == EMC_C_PARAMETER) c->d.par[v->index] = value[i];
        else if (v->kind == EMC_C_GAIN) c->d.gain[v->index] = value[i];
        else if (v->kind == EMC_C_INPUT) { c->d.in[v->index] = value[i]; c->d.rate[v->index] = 0.0; }
    }
    return fmi2OK;
}

fmi2Status fmi2GetInteger(fmi2Component component, const fmi2ValueReference vr[], size_t nvr, fmi2Integer value[])
{
    size_t i;
    ENTER("fmi2GetInteger", M_ANY);
    if (check_references(c, "fmi2GetInteger", vr, nvr, value) != fmi2OK) return fmi2Error;
    for (i = 0; i < nvr; i++) {
        if (EMC_VARIABLES[vr[i]].kind != EMC_C_STRICT)
            return fail(c, fmi2Error, "fmi2GetInteger: %s is a Real variable", EMC_VARIABLES[vr[i]].name);
        value[i] = c->d.strict;
    }
    return fmi2OK;
}

fmi2Status fmi2SetInteger(fmi2Component component, const fmi2ValueReference vr[], size_t nvr, const fmi2Integer value[])
{
    size_t i;
    ENTER("fmi2SetInteger", M_INSTANTIATED | M_INITIALIZATION);
    if (check_references(c, "fmi2SetInteger", vr, nvr, value) != fmi2OK) return fmi2Error;
    for (i = 0; i < nvr; i++)
        if (EMC_VARIABLES[vr[i]].kind != EMC_C_STRICT)
            return fail(c, fmi2Error, "fmi2SetInteger: %s is a Real variable", EMC_VARIABLES[vr[i]].name);
    for (i = 0; i < nvr; i++) c->d.strict = value[i];
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

/* ---- FMU state: a fixed pool inside the instance ------------------------------------------------ */
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
    if (s->magic != EMC_STATE_MAGIC || !(s->mode & M_ANY) || (s->mode & (s->mode - 1))
        || ((s->mode & (M_EVENT | M_CONTINUOUS)) && c->interface != fmi2ModelExchange)
        || ((s->mode & M_STEP) && c->interface != fmi2CoSimulation) || (s->strict != 0 && s->strict != 1))
        return fail(c, fmi2Error, "%s: not an FMU state of %s", function, EMC_MODEL_IDENTIFIER);
    if (!isfinite(s->time) || !isfinite(s->start_time) || !all_finite(s->par, EMC_N_PARAMETERS)
        || !all_finite(s->gain, EMC_N_GAINS) || !all_finite(s->in, EMC_NI) || !all_finite(s->rate, EMC_NI))
        return fail(c, fmi2Error, "%s: the FMU state holds values that are not finite", function);
    if ((s->mode & M_INITIALIZED) && check_design(c, function, s) != fmi2OK) return fmi2Error;
    return fmi2OK;
}

fmi2Status fmi2GetFMUstate(fmi2Component component, fmi2FMUstate *FMUstate)
{
    emc_data *slot;
    ENTER("fmi2GetFMUstate", M_ANY);
    if (FMUstate == NULL) return fail(c, fmi2Error, "fmi2GetFMUstate: FMUstate is NULL");
    slot = free_slot(c, *FMUstate);
    if (slot == NULL)
        return fail(c, fmi2Error, "fmi2GetFMUstate: no free FMU state (%d at most) or *FMUstate is not one of this "
                    "instance's", EMC_STATE_POOL);
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

/* ---- derivatives: du/d inputs from the symbolic Jacobian (components.laws) ------------------------- */
static fmi2Status du_along(emc_instance *c, const char *function, const double *direction, double *out)
{
    double J[EMC_N_OUTPUTS * EMC_NI], u[EMC_N_OUTPUTS];
    int i, k;
    if (compute_u(c, function, fmi2Error, u, J) != fmi2OK) return fmi2Error;
    for (k = 0; k < EMC_N_OUTPUTS; k++) {
        out[k] = 0.0;
        for (i = 0; i < EMC_NI; i++) out[k] += J[k * EMC_NI + i] * direction[i];
        if (!isfinite(out[k]))
            return fail(c, fmi2Error, "%s at t = %.9g s: the derivative of u is not finite", function, c->d.time);
    }
    return fmi2OK;
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component component, const fmi2ValueReference vUnknown_ref[], size_t nUnknown,
                                        const fmi2ValueReference vKnown_ref[], size_t nKnown,
                                        const fmi2Real dvKnown[], fmi2Real dvUnknown[])
{
    double v[EMC_NI], d[EMC_N_OUTPUTS];
    size_t i;
    ENTER("fmi2GetDirectionalDerivative", M_INITIALIZATION | M_INITIALIZED);
    if (check_references(c, "fmi2GetDirectionalDerivative", vUnknown_ref, nUnknown, dvUnknown) != fmi2OK
        || check_references(c, "fmi2GetDirectionalDerivative", vKnown_ref, nKnown, dvKnown) != fmi2OK)
        return fmi2Error;
    memset(v, 0, sizeof v);
    for (i = 0; i < nKnown; i++) {
        const emc_c_variable *w = &EMC_VARIABLES[vKnown_ref[i]];
        if (w->kind != EMC_C_INPUT)
            return fail(c, fmi2Error, "fmi2GetDirectionalDerivative: %s is not a known (an input)", w->name);
        if (!isfinite(dvKnown[i]))
            return fail(c, fmi2Error, "fmi2GetDirectionalDerivative: the seed of %s is not finite", w->name);
        v[w->index] += dvKnown[i];
    }
    for (i = 0; i < nUnknown; i++)
        if (EMC_VARIABLES[vUnknown_ref[i]].kind != EMC_C_OUTPUT)
            return fail(c, fmi2Error, "fmi2GetDirectionalDerivative: %s is not an unknown (an output)",
                        EMC_VARIABLES[vUnknown_ref[i]].name);
    if (nUnknown == 0) return fmi2OK;
    if (du_along(c, "fmi2GetDirectionalDerivative", v, d) != fmi2OK) return fmi2Error;
    for (i = 0; i < nUnknown; i++) dvUnknown[i] = d[EMC_VARIABLES[vUnknown_ref[i]].index];
    return fmi2OK;
}

/* ---- Co-Simulation -------------------------------------------------------------------------------- */
fmi2Status fmi2SetRealInputDerivatives(fmi2Component component, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[])
{
    size_t i;
    ENTER("fmi2SetRealInputDerivatives", M_INITIALIZATION | M_STEP);
    ONLY("fmi2SetRealInputDerivatives", fmi2CoSimulation);
    if (check_references(c, "fmi2SetRealInputDerivatives", vr, nvr, value) != fmi2OK) return fmi2Error;
    if (nvr > 0 && order == NULL) return fail(c, fmi2Error, "fmi2SetRealInputDerivatives: order is NULL");
    for (i = 0; i < nvr; i++) {
        const emc_c_variable *v = &EMC_VARIABLES[vr[i]];
        if (v->kind != EMC_C_INPUT) return fail(c, fmi2Error, "fmi2SetRealInputDerivatives: %s is not a Real input", v->name);
        if (order[i] < 1)
            return fail(c, fmi2Error, "fmi2SetRealInputDerivatives: order %d for input %s is not an integer >= 1",
                        (int)order[i], v->name);
        if (!isfinite(value[i]))
            return fail(c, fmi2Error, "fmi2SetRealInputDerivatives: derivative of order %d of input %s = %g is not finite",
                        (int)order[i], v->name, value[i]);
    }
    for (i = 0; i < nvr; i++)                 /* orders >= 2 are dropped: du/dt needs the first ones only */
        if (order[i] == 1) c->d.rate[EMC_VARIABLES[vr[i]].index] = value[i];
    return fmi2OK;
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component component, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[])
{
    size_t i;
    double d[EMC_N_OUTPUTS];
    ENTER("fmi2GetRealOutputDerivatives", M_INITIALIZATION | M_STEP | M_TERMINATED);
    ONLY("fmi2GetRealOutputDerivatives", fmi2CoSimulation);
    if (check_references(c, "fmi2GetRealOutputDerivatives", vr, nvr, value) != fmi2OK) return fmi2Error;
    if (nvr > 0 && order == NULL) return fail(c, fmi2Error, "fmi2GetRealOutputDerivatives: order is NULL");
    for (i = 0; i < nvr; i++) {
        if (EMC_VARIABLES[vr[i]].kind != EMC_C_OUTPUT)
            return fail(c, fmi2Error, "fmi2GetRealOutputDerivatives: %s is not a Real output", EMC_VARIABLES[vr[i]].name);
        if (order[i] != 1)
            return fail(c, fmi2Error, "fmi2GetRealOutputDerivatives: order %d for output %s is not in 1..1", (int)order[i],
                        EMC_VARIABLES[vr[i]].name);
    }
    if (nvr == 0) return fmi2OK;
    if (du_along(c, "fmi2GetRealOutputDerivatives", c->d.rate, d) != fmi2OK) return fmi2Error;
    for (i = 0; i < nvr; i++) value[i] = d[EMC_VARIABLES[vr[i]].index];
    return fmi2OK;
}

fmi2Status fmi2DoStep(fmi2Component component, fmi2Real currentCommunicationPoint, fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint)
{
    double u[EMC_N_OUTPUTS], scale;
    char where[64];
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
    snprintf(where, sizeof where, "fmi2DoStep");
    if (compute_u(c, where, fmi2Discard, u, NULL) != fmi2OK) return fmi2Discard;
    memset(c->d.rate, 0, sizeof c->d.rate);     /* set again by the master for the next step */
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

/* a vector of zero entries: fmi2OK for nx = 0, whatever the pointer */
#define NO_STATES(function, mask, constness)                                                          \
    fmi2Status function(fmi2Component component, constness fmi2Real x[], size_t nx)                   \
    {                                                                                                 \
        ENTER(#function, mask);                                                                       \
        ONLY(#function, fmi2ModelExchange);                                                           \
        (void)x;                                                                                      \
        if (nx != 0) return fail(c, fmi2Error, "%s: %zu values for 0 (the controller has no states)", #function, nx); \
        return fmi2OK;                                                                                \
    }
NO_STATES(fmi2SetContinuousStates, M_CONTINUOUS, const)
NO_STATES(fmi2GetDerivatives, M_EVENT | M_CONTINUOUS | M_TERMINATED, )
NO_STATES(fmi2GetEventIndicators, M_INITIALIZATION | M_INITIALIZED, )
NO_STATES(fmi2GetContinuousStates, M_INITIALIZATION | M_INITIALIZED, )
NO_STATES(fmi2GetNominalsOfContinuousStates, M_INSTANTIATED | M_EVENT | M_CONTINUOUS | M_TERMINATED, )
