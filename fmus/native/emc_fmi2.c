/* emcosim's FMI 2.0 framework in C: every FMI 2.0 function, for any model kind (emc_fmi2.h says what a kind
 * supplies; emc_plant.c, emc_controller.c, emc_reference.c are the kinds; docs/native-fmus.md).
 *
 * Rules kept by every function: the instance is checked, then the mode (a call outside the state machine of
 * FMI 2.0 sections 3.2.3 and 4.2.4 is refused with fmi2Error and one log line naming the function and the
 * mode; a function of the other interface likewise), then every argument, before anything is read or the
 * model is called. A value that is not finite is never set and never returned.
 *
 * Real-time fitness: the only allocation is the instance in fmi2Instantiate (the current data, a scratch copy
 * and a fixed pool of EMC_STATE_POOL FMU states, all of EMC_DATA_SIZE bytes); no function here loops over
 * more than its arguments or the pool; there are no writable globals, so instances are independent across
 * threads (each instance used by one thread at a time, as FMI 2.0 asks).
 */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "emc_config.h"
#include "emc_fmi2.h"

#define EMC_MAGIC 0x656d636fu              /* "emco": a live instance */
#define EMC_DATA_MAGIC 0x656d7374u         /* "emst": a model's data (current or saved) */
#define EMC_STATE_POOL 8                   /* FMU states an instance can hold at once (fmi2GetFMUstate) */
#define EMC_MESSAGE 1024                  /* a design check's warning lists every failed condition */
#define EMC_TIME_TOLERANCE 1e-12           /* fmus/slave.py: COMMUNICATION_POINT_TOLERANCE */

struct emc_instance {
    unsigned magic;
    fmi2Type interface;
    fmi2CallbackFunctions functions;
    char name[128];
    int logging;
    size_t slot;                           /* bytes of one data slot: EMC_DATA_SIZE rounded up to doubles */
    emc_common *d;                         /* the current data */
    emc_common *scratch;                   /* a deserialized state while it is checked */
    double storage[];                      /* current, scratch, then the EMC_STATE_POOL slots of the pool */
};

static emc_common *slot_at(emc_instance *c, int i)    /* 0 current, 1 scratch, 2.. the pool */
{
    return (emc_common *)((unsigned char *)c->storage + (size_t)i * c->slot);
}

static emc_common *pool_at(emc_instance *c, int i) { return slot_at(c, 2 + i); }

const char *emc_mode_name(int mode)
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

fmi2Type emc_interface(const emc_instance *c) { return c->interface; }

int emc_all_finite(const double *v, size_t n)
{
    size_t i;
    for (i = 0; i < n; i++)
        if (!isfinite(v[i])) return 0;
    return 1;
}

/* The message goes to the host formatted, "<model identifier>: <text>", with no variadic arguments and every
 * '%' doubled: FMI 2.0 makes the message a printf format, so a C host that formats it (fmusim, the FMU
 * Compliance Checker) prints the text, and a host whose ctypes logger cannot read variadic arguments (fmpy,
 * the engine's emcosim.engine.fmi.instantiate) gets the text too instead of a bare "%s: %s". The pythonfmu
 * FMUs' loader (fmus/emcosim_fmu_loader.c, log_text) sends its messages the same way. */
static void log_to(fmi2CallbackLogger logger, fmi2ComponentEnvironment environment, const char *name,
                   fmi2Status status, const char *category, const char *format, va_list args)
{
    char text[EMC_MESSAGE];
    char escaped[2 * EMC_MESSAGE];
    size_t i, n = 0;
    int head = snprintf(text, sizeof text, "%s: ", EMC_MODEL_IDENTIFIER);
    if (head < 0 || (size_t)head >= sizeof text) head = 0;
    vsnprintf(text + head, sizeof text - (size_t)head, format, args);
    for (i = 0; text[i] != '\0'; i++) {
        if (text[i] == '%') escaped[n++] = '%';
        escaped[n++] = text[i];
    }
    escaped[n] = '\0';
    logger(environment, name, status, category, escaped);
}

static void vlog(emc_instance *c, fmi2Status status, const char *category, const char *format, va_list args)
{
    if (c == NULL || c->functions.logger == NULL || (status == fmi2OK && !c->logging))
        return;
    log_to(c->functions.logger, c->functions.componentEnvironment, c->name, status, category, format, args);
}

fmi2Status emc_fail(emc_instance *c, fmi2Status status, const char *format, ...)
{
    va_list args;
    va_start(args, format);
    vlog(c, status, status == fmi2Warning ? "logStatusWarning" : status == fmi2Discard ? "logStatusDiscard" : "logStatusError",
         format, args);
    va_end(args);
    return status;
}

/* the instance, or NULL (nothing can be logged without one) */
static emc_instance *instance(fmi2Component component)
{
    emc_instance *c = (emc_instance *)component;
    return (c != NULL && c->magic == EMC_MAGIC) ? c : NULL;
}

#define ENTER(function, mask)                                                                       \
    emc_instance *c = instance(component);                                                          \
    if (c == NULL) return fmi2Error;                                                                \
    if (!(c->d->mode & (mask)))                                                                     \
        return emc_fail(c, fmi2Error, "%s is not allowed %s", function, emc_mode_name(c->d->mode))

/* a function of one interface only */
#define ONLY(function, kind)                                                                       \
    if (c->interface != kind)                                                                      \
        return emc_fail(c, fmi2Error, "%s is not a function of %s", function,                      \
                        c->interface == fmi2ModelExchange ? "Model Exchange" : "Co-Simulation")

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
        return emc_fail(c, fmi2Error, "fmi2SetDebugLogging: categories is NULL with nCategories = %zu", nCategories);
    for (i = 0; i < nCategories; i++) {
        if (categories[i] == NULL)
            return emc_fail(c, fmi2Error, "fmi2SetDebugLogging: category %zu is NULL", i);
        if (strcmp(categories[i], "logStatusWarning") && strcmp(categories[i], "logStatusDiscard")
            && strcmp(categories[i], "logStatusError") && strcmp(categories[i], "logStatusFatal")
            && strcmp(categories[i], "logAll"))
            return emc_fail(c, fmi2Error, "fmi2SetDebugLogging: unknown log category \"%s\"", categories[i]);
    }
    c->logging = loggingOn ? 1 : 0;
    return fmi2OK;
}

static void reset(emc_common *d)
{
    memset(d, 0, EMC_DATA_SIZE);
    emc_reset(d);
    d->magic = EMC_DATA_MAGIC;
    d->mode = M_INSTANTIATED;
    d->in_use = 0;
}

/* fmi2Instantiate's refusal: one message if the host gave a logger, and no instance. */
static fmi2Component refuse(fmi2CallbackLogger logger, fmi2ComponentEnvironment environment, const char *name,
                            const char *format, ...)
{
    va_list args;
    if (logger != NULL) {
        va_start(args, format);
        log_to(logger, environment, name, fmi2Error, "logStatusError", format, args);
        va_end(args);
    }
    return NULL;
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation, const fmi2CallbackFunctions *functions,
                              fmi2Boolean visible, fmi2Boolean loggingOn)
{
    emc_instance *c;
    fmi2CallbackLogger logger = functions != NULL ? functions->logger : NULL;
    void *environment = functions != NULL ? functions->componentEnvironment : NULL;
    const char *name = (instanceName != NULL && instanceName[0] != '\0') ? instanceName : "?";
    const size_t slot = (EMC_DATA_SIZE + sizeof(double) - 1) / sizeof(double) * sizeof(double);
    (void)fmuResourceLocation;
    (void)visible;
#define REFUSE(...) return refuse(logger, environment, name, __VA_ARGS__)
    if (functions == NULL) return NULL;
    if (instanceName == NULL || instanceName[0] == '\0')
        REFUSE("fmi2Instantiate: the instance name is empty");
    if (fmuType != fmi2ModelExchange && fmuType != fmi2CoSimulation)
        REFUSE("fmi2Instantiate: fmuType %d is neither fmi2ModelExchange (0) nor fmi2CoSimulation (1)",
               (int)fmuType);
    if (fmuGUID == NULL || strcmp(fmuGUID, EMC_GUID) != 0)
        REFUSE("fmi2Instantiate: GUID %s does not match the FMU's %s", fmuGUID ? fmuGUID : "(null)", EMC_GUID);
    /* the only allocation of an instance's life: the instance, its data, a scratch copy and the pool */
    c = (emc_instance *)calloc(1, sizeof *c + (2 + EMC_STATE_POOL) * slot);
    if (c == NULL)
        REFUSE("fmi2Instantiate: out of memory");
#undef REFUSE
    c->magic = EMC_MAGIC;
    c->interface = fmuType;
    c->functions = *functions;
    snprintf(c->name, sizeof c->name, "%s", instanceName);
    c->logging = loggingOn ? 1 : 0;
    c->slot = slot;
    c->d = slot_at(c, 0);
    c->scratch = slot_at(c, 1);
    reset(c->d);
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
        return emc_fail(c, fmi2Error, "fmi2SetupExperiment: tolerance = %g is not finite and > 0", tolerance);
    if (!isfinite(startTime))
        return emc_fail(c, fmi2Error, "fmi2SetupExperiment: startTime = %g is not finite", startTime);
    if (stopTimeDefined && !(stopTime >= startTime))
        return emc_fail(c, fmi2Error, "fmi2SetupExperiment: stopTime = %g is not >= startTime = %g", stopTime, startTime);
    c->d->time = c->d->start_time = startTime;
    c->d->tolerance_defined = toleranceDefined ? 1 : 0;
    c->d->tolerance = toleranceDefined ? tolerance : 0.0;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component component)
{
    ENTER("fmi2EnterInitializationMode", M_INSTANTIATED);
    c->d->mode = M_INITIALIZATION;
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component component)
{
    ENTER("fmi2ExitInitializationMode", M_INITIALIZATION);
    if (emc_exit_initialization(c, c->d) != fmi2OK) return fmi2Error;
    c->d->mode = c->interface == fmi2CoSimulation ? M_STEP : M_EVENT;
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component component)
{
    ENTER("fmi2Terminate", M_EVENT | M_CONTINUOUS | M_STEP);
    c->d->mode = M_TERMINATED;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component component)
{
    emc_instance *c = instance(component);
    if (c == NULL) return fmi2Error;
    reset(c->d);
    return fmi2OK;
}

/* ---- get and set -------------------------------------------------------------------------------- */
/* vr and value not NULL (nvr > 0) and every reference existing */
static fmi2Status check_references(emc_instance *c, const char *function, const fmi2ValueReference vr[], size_t nvr,
                                   const void *value)
{
    size_t i;
    if (nvr == 0) return fmi2OK;
    if (vr == NULL || value == NULL)
        return emc_fail(c, fmi2Error, "%s: vr or value is NULL with nvr = %zu", function, nvr);
    for (i = 0; i < nvr; i++)
        if (vr[i] >= EMC_VARIABLE_COUNT)
            return emc_fail(c, fmi2Error, "%s: value reference %u does not exist (0 to %u)", function, vr[i],
                            EMC_VARIABLE_COUNT - 1);
    return fmi2OK;
}

/* every reference of the type the function gets or sets (Integer or Real) */
static fmi2Status check_type(emc_instance *c, const char *function, const fmi2ValueReference vr[], size_t nvr,
                             int integer)
{
    size_t i;
    for (i = 0; i < nvr; i++)
        if ((emc_role_of(vr[i]) == EMC_ROLE_INTEGER_PARAMETER) != integer)
            return emc_fail(c, fmi2Error, "%s: %s is %s variable", function, emc_name_of(vr[i]),
                            integer ? "a Real" : "an Integer");
    return fmi2OK;
}

/* may the variable be set now (fmi2SetReal, fmi2SetInteger)? */
static fmi2Status check_settable(emc_instance *c, const char *function, fmi2ValueReference vr)
{
    emc_role role = emc_role_of(vr);
    if (role == EMC_ROLE_OUTPUT)
        return emc_fail(c, fmi2Error, "%s: %s is an output and cannot be set", function, emc_name_of(vr));
    if (role != EMC_ROLE_INPUT && !(c->d->mode & (M_INSTANTIATED | M_INITIALIZATION)))
        return emc_fail(c, fmi2Error, "%s: the parameter %s cannot be set %s", function, emc_name_of(vr),
                        emc_mode_name(c->d->mode));
    return fmi2OK;
}

fmi2Status fmi2GetReal(fmi2Component component, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[])
{
    size_t i;
    ENTER("fmi2GetReal", M_INITIALIZATION | M_INITIALIZED);
    if (check_references(c, "fmi2GetReal", vr, nvr, value) != fmi2OK
        || check_type(c, "fmi2GetReal", vr, nvr, 0) != fmi2OK)
        return fmi2Error;
    if (nvr == 0) return fmi2OK;
    if (emc_get_reals(c, c->d, vr, nvr, value) != fmi2OK) return fmi2Error;
    for (i = 0; i < nvr; i++)
        if (!isfinite(value[i]))
            return emc_fail(c, fmi2Error, "fmi2GetReal: %s is not finite at t = %.9g s", emc_name_of(vr[i]), c->d->time);
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component component, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[])
{
    size_t i;
    ENTER("fmi2SetReal", M_INSTANTIATED | M_INITIALIZATION | M_EVENT | M_CONTINUOUS | M_STEP);
    if (check_references(c, "fmi2SetReal", vr, nvr, value) != fmi2OK
        || check_type(c, "fmi2SetReal", vr, nvr, 0) != fmi2OK)
        return fmi2Error;
    for (i = 0; i < nvr; i++) {           /* all checked before any is set */
        if (check_settable(c, "fmi2SetReal", vr[i]) != fmi2OK) return fmi2Error;
        if (!isfinite(value[i]))
            return emc_fail(c, fmi2Error, "fmi2SetReal: %s = %g is not finite", emc_name_of(vr[i]), value[i]);
    }
    for (i = 0; i < nvr; i++) emc_set_real(c->d, vr[i], value[i]);
    return fmi2OK;
}

fmi2Status fmi2GetInteger(fmi2Component component, const fmi2ValueReference vr[], size_t nvr, fmi2Integer value[])
{
    size_t i;
    ENTER("fmi2GetInteger", M_ANY);
    if (check_references(c, "fmi2GetInteger", vr, nvr, value) != fmi2OK
        || check_type(c, "fmi2GetInteger", vr, nvr, 1) != fmi2OK)
        return fmi2Error;
    for (i = 0; i < nvr; i++) value[i] = emc_get_integer(c->d, vr[i]);
    return fmi2OK;
}

fmi2Status fmi2SetInteger(fmi2Component component, const fmi2ValueReference vr[], size_t nvr, const fmi2Integer value[])
{
    size_t i;
    /* allowed wherever FMI 2.0 allows fmi2SetInteger (a generic host sets no variable, nvr = 0, in any such
       mode); an Integer parameter only before fmi2ExitInitializationMode (check_settable) */
    ENTER("fmi2SetInteger", M_INSTANTIATED | M_INITIALIZATION | M_EVENT | M_CONTINUOUS | M_STEP);
    if (check_references(c, "fmi2SetInteger", vr, nvr, value) != fmi2OK
        || check_type(c, "fmi2SetInteger", vr, nvr, 1) != fmi2OK)
        return fmi2Error;
    for (i = 0; i < nvr; i++)
        if (check_settable(c, "fmi2SetInteger", vr[i]) != fmi2OK) return fmi2Error;
    for (i = 0; i < nvr; i++) emc_set_integer(c->d, vr[i], value[i]);   /* the model checks the value at exit */
    return fmi2OK;
}

#define NO_VARIABLES(function, type, constness)                                                       \
    fmi2Status function(fmi2Component component, const fmi2ValueReference vr[], size_t nvr, constness type value[]) \
    {                                                                                                 \
        ENTER(#function, M_ANY);                                                                      \
        (void)value;                                                                                  \
        if (nvr == 0) return fmi2OK;                                                                  \
        if (vr == NULL) return emc_fail(c, fmi2Error, "%s: vr is NULL with nvr = %zu", #function, nvr); \
        return emc_fail(c, fmi2Error, "%s: value reference %u is not of this type (none is)", #function, vr[0]); \
    }
NO_VARIABLES(fmi2GetBoolean, fmi2Boolean, )
NO_VARIABLES(fmi2GetString, fmi2String, )
NO_VARIABLES(fmi2SetBoolean, fmi2Boolean, const)
NO_VARIABLES(fmi2SetString, fmi2String, const)

/* ---- FMU state: a fixed pool inside the instance (no allocation) ---------------------------------- */
static emc_common *pooled(emc_instance *c, fmi2FMUstate s)
{
    int i;
    for (i = 0; i < EMC_STATE_POOL; i++)
        if (s == (fmi2FMUstate)pool_at(c, i) && pool_at(c, i)->in_use) return pool_at(c, i);
    return NULL;
}

/* the slot *FMUstate names (one of this instance's) or, if *FMUstate is NULL, a free one; NULL with a log line */
static emc_common *slot_for(emc_instance *c, const char *function, fmi2FMUstate current)
{
    int i;
    if (current != NULL) {
        emc_common *s = pooled(c, current);
        if (s == NULL) emc_fail(c, fmi2Error, "%s: *FMUstate is not a state of this instance", function);
        return s;
    }
    for (i = 0; i < EMC_STATE_POOL; i++)
        if (!pool_at(c, i)->in_use) return pool_at(c, i);
    emc_fail(c, fmi2Error, "%s: all %d FMU states of this instance are in use (free one with fmi2FreeFMUstate)",
             function, EMC_STATE_POOL);
    return NULL;
}

/* a saved state: its magic, one mode valid for the interface, finite times; then the model's checks */
static fmi2Status check_saved(emc_instance *c, const char *function, const emc_common *s)
{
    if (s->magic != EMC_DATA_MAGIC || !(s->mode & M_ANY) || (s->mode & (s->mode - 1))
        || ((s->mode & (M_EVENT | M_CONTINUOUS)) && c->interface != fmi2ModelExchange)
        || ((s->mode & M_STEP) && c->interface != fmi2CoSimulation))
        return emc_fail(c, fmi2Error, "%s: not an FMU state of %s", function, EMC_MODEL_IDENTIFIER);
    if (!isfinite(s->time) || !isfinite(s->start_time) || !isfinite(s->tolerance))
        return emc_fail(c, fmi2Error, "%s: the FMU state holds values that are not finite", function);
    return emc_check_saved(c, function, s);
}

fmi2Status fmi2GetFMUstate(fmi2Component component, fmi2FMUstate *FMUstate)
{
    emc_common *slot;
    ENTER("fmi2GetFMUstate", M_ANY);
    if (FMUstate == NULL) return emc_fail(c, fmi2Error, "fmi2GetFMUstate: FMUstate is NULL");
    slot = slot_for(c, "fmi2GetFMUstate", *FMUstate);
    if (slot == NULL) return fmi2Error;
    memcpy(slot, c->d, EMC_DATA_SIZE);
    slot->in_use = 1;
    *FMUstate = (fmi2FMUstate)slot;
    return fmi2OK;
}

fmi2Status fmi2SetFMUstate(fmi2Component component, fmi2FMUstate FMUstate)
{
    emc_common *s;
    ENTER("fmi2SetFMUstate", M_ANY);
    s = pooled(c, FMUstate);
    if (s == NULL) return emc_fail(c, fmi2Error, "fmi2SetFMUstate: not an FMU state of this instance");
    if (check_saved(c, "fmi2SetFMUstate", s) != fmi2OK) return fmi2Error;
    memcpy(c->d, s, EMC_DATA_SIZE);
    c->d->in_use = 0;
    return fmi2OK;
}

fmi2Status fmi2FreeFMUstate(fmi2Component component, fmi2FMUstate *FMUstate)
{
    emc_common *s;
    ENTER("fmi2FreeFMUstate", M_ANY);
    if (FMUstate == NULL) return emc_fail(c, fmi2Error, "fmi2FreeFMUstate: FMUstate is NULL");
    if (*FMUstate == NULL) return fmi2OK;
    s = pooled(c, *FMUstate);
    if (s == NULL) return emc_fail(c, fmi2Error, "fmi2FreeFMUstate: not an FMU state of this instance");
    s->in_use = 0;
    *FMUstate = NULL;
    return fmi2OK;
}

/* serialized: EMC_GUID (with its terminating zero) then the model's data bytes */
#define EMC_SERIAL_SIZE (sizeof(EMC_GUID) + EMC_DATA_SIZE)

fmi2Status fmi2SerializedFMUstateSize(fmi2Component component, fmi2FMUstate FMUstate, size_t *size)
{
    ENTER("fmi2SerializedFMUstateSize", M_ANY);
    if (size == NULL) return emc_fail(c, fmi2Error, "fmi2SerializedFMUstateSize: size is NULL");
    if (pooled(c, FMUstate) == NULL)
        return emc_fail(c, fmi2Error, "fmi2SerializedFMUstateSize: not an FMU state of this instance");
    *size = EMC_SERIAL_SIZE;
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component component, fmi2FMUstate FMUstate, fmi2Byte serializedState[], size_t size)
{
    emc_common *s;
    ENTER("fmi2SerializeFMUstate", M_ANY);
    s = pooled(c, FMUstate);
    if (s == NULL) return emc_fail(c, fmi2Error, "fmi2SerializeFMUstate: not an FMU state of this instance");
    if (serializedState == NULL || size != EMC_SERIAL_SIZE)
        return emc_fail(c, fmi2Error, "fmi2SerializeFMUstate: a buffer of %zu bytes is needed", (size_t)EMC_SERIAL_SIZE);
    memcpy(serializedState, EMC_GUID, sizeof(EMC_GUID));
    memcpy(serializedState + sizeof(EMC_GUID), s, EMC_DATA_SIZE);
    return fmi2OK;
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component component, const fmi2Byte serializedState[], size_t size,
                                   fmi2FMUstate *FMUstate)
{
    emc_common *slot;
    ENTER("fmi2DeSerializeFMUstate", M_ANY);
    if (serializedState == NULL || FMUstate == NULL)
        return emc_fail(c, fmi2Error, "fmi2DeSerializeFMUstate: serializedState or FMUstate is NULL");
    if (size != EMC_SERIAL_SIZE || memcmp(serializedState, EMC_GUID, sizeof(EMC_GUID)) != 0)
        return emc_fail(c, fmi2Error, "fmi2DeSerializeFMUstate: not a serialized FMU state of this FMU (%zu bytes)", size);
    memcpy(c->scratch, serializedState + sizeof(EMC_GUID), EMC_DATA_SIZE);
    if (check_saved(c, "fmi2DeSerializeFMUstate", c->scratch) != fmi2OK) return fmi2Error;
    slot = slot_for(c, "fmi2DeSerializeFMUstate", *FMUstate);
    if (slot == NULL) return fmi2Error;
    memcpy(slot, c->scratch, EMC_DATA_SIZE);
    slot->in_use = 1;
    *FMUstate = (fmi2FMUstate)slot;
    return fmi2OK;
}

/* ---- directional derivatives ---------------------------------------------------------------------- */
fmi2Status fmi2GetDirectionalDerivative(fmi2Component component, const fmi2ValueReference vUnknown_ref[], size_t nUnknown,
                                        const fmi2ValueReference vKnown_ref[], size_t nKnown,
                                        const fmi2Real dvKnown[], fmi2Real dvUnknown[])
{
    size_t i;
    ENTER("fmi2GetDirectionalDerivative", M_INITIALIZATION | M_INITIALIZED);
    if (check_references(c, "fmi2GetDirectionalDerivative", vUnknown_ref, nUnknown, dvUnknown) != fmi2OK
        || check_references(c, "fmi2GetDirectionalDerivative", vKnown_ref, nKnown, dvKnown) != fmi2OK)
        return fmi2Error;
    for (i = 0; i < nKnown; i++)
        if (!isfinite(dvKnown[i]))
            return emc_fail(c, fmi2Error, "fmi2GetDirectionalDerivative: the seed of %s is not finite",
                            emc_name_of(vKnown_ref[i]));
    if (emc_directional_derivative(c, c->d, vUnknown_ref, nUnknown, vKnown_ref, nKnown, dvKnown, dvUnknown) != fmi2OK)
        return fmi2Error;
    for (i = 0; i < nUnknown; i++)
        if (!isfinite(dvUnknown[i]))
            return emc_fail(c, fmi2Error, "fmi2GetDirectionalDerivative: d %s is not finite at t = %.9g s",
                            emc_name_of(vUnknown_ref[i]), c->d->time);
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
    if (nvr > 0 && order == NULL) return emc_fail(c, fmi2Error, "fmi2SetRealInputDerivatives: order is NULL");
    for (i = 0; i < nvr; i++) {               /* all or nothing */
        if (emc_role_of(vr[i]) != EMC_ROLE_INPUT)
            return emc_fail(c, fmi2Error, "fmi2SetRealInputDerivatives: %s is not a Real input", emc_name_of(vr[i]));
        if (order[i] < 1)
            return emc_fail(c, fmi2Error, "fmi2SetRealInputDerivatives: order %d for input %s is not an integer >= 1",
                            (int)order[i], emc_name_of(vr[i]));
        if (!isfinite(value[i]))
            return emc_fail(c, fmi2Error, "fmi2SetRealInputDerivatives: derivative of order %d of input %s = %g is not "
                            "finite", (int)order[i], emc_name_of(vr[i]), value[i]);
    }
    if (nvr == 0) return fmi2OK;
    return emc_set_input_derivatives(c, c->d, vr, nvr, order, value);
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component component, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[])
{
    size_t i;
    ENTER("fmi2GetRealOutputDerivatives", M_INITIALIZATION | M_STEP | M_TERMINATED);
    ONLY("fmi2GetRealOutputDerivatives", fmi2CoSimulation);
    if (check_references(c, "fmi2GetRealOutputDerivatives", vr, nvr, value) != fmi2OK) return fmi2Error;
    if (nvr > 0 && order == NULL) return emc_fail(c, fmi2Error, "fmi2GetRealOutputDerivatives: order is NULL");
    if (nvr == 0) return fmi2OK;
    if (emc_get_output_derivatives(c, c->d, vr, nvr, order, value) != fmi2OK) return fmi2Error;
    for (i = 0; i < nvr; i++)
        if (!isfinite(value[i]))
            return emc_fail(c, fmi2Error, "fmi2GetRealOutputDerivatives: d^%d %s/dt^%d is not finite at t = %.9g s",
                            (int)order[i], emc_name_of(vr[i]), (int)order[i], c->d->time);
    return fmi2OK;
}

fmi2Status fmi2DoStep(fmi2Component component, fmi2Real currentCommunicationPoint, fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint)
{
    double scale;
    fmi2Status status;
    ENTER("fmi2DoStep", M_STEP);
    ONLY("fmi2DoStep", fmi2CoSimulation);
    (void)noSetFMUStatePriorToCurrentPoint;
    if (!(isfinite(currentCommunicationPoint) && isfinite(communicationStepSize) && communicationStepSize > 0.0))
        return emc_fail(c, fmi2Error, "fmi2DoStep: currentCommunicationPoint = %g, communicationStepSize = %g: both must "
                        "be finite and the step > 0", currentCommunicationPoint, communicationStepSize);
    if (!isfinite(currentCommunicationPoint + communicationStepSize))      /* the time would become inf */
        return emc_fail(c, fmi2Error, "fmi2DoStep: currentCommunicationPoint + communicationStepSize = %.17g + %.17g "
                        "overflows", currentCommunicationPoint, communicationStepSize);
    scale = fmax(fmax(fabs(c->d->time), fabs(currentCommunicationPoint)), fmax(fabs(c->d->start_time), communicationStepSize));
    if (fabs(currentCommunicationPoint - c->d->time) > EMC_TIME_TOLERANCE * scale)
        return emc_fail(c, fmi2Error, "fmi2DoStep: currentCommunicationPoint = %.17g s is not this FMU's time %.17g s",
                        currentCommunicationPoint, c->d->time);
    status = emc_do_step(c, c->d, communicationStepSize);
    if (status != fmi2OK) return status;
    c->d->time = currentCommunicationPoint + communicationStepSize;
    return fmi2OK;
}

fmi2Status fmi2CancelStep(fmi2Component component)
{
    ENTER("fmi2CancelStep", M_STEP);
    return emc_fail(c, fmi2Error, "fmi2CancelStep: doStep never runs asynchronously here; there is nothing to cancel");
}

#define STATUS(function, type)                                                                        \
    fmi2Status function(fmi2Component component, const fmi2StatusKind s, type *value)                 \
    {                                                                                                 \
        ENTER(#function, M_STEP | M_TERMINATED);                                                      \
        ONLY(#function, fmi2CoSimulation);                                                            \
        (void)s;                                                                                      \
        (void)value;                                                                                  \
        return emc_fail(c, fmi2Discard, "%s: doStep never runs asynchronously here (no status to ask)", #function); \
    }
STATUS(fmi2GetStatus, fmi2Status)
STATUS(fmi2GetIntegerStatus, fmi2Integer)
STATUS(fmi2GetStringStatus, fmi2String)

/* fmi2LastSuccessfulTime: the FMU's time (the end of its last successful step) */
fmi2Status fmi2GetRealStatus(fmi2Component component, const fmi2StatusKind s, fmi2Real *value)
{
    ENTER("fmi2GetRealStatus", M_STEP | M_TERMINATED);
    ONLY("fmi2GetRealStatus", fmi2CoSimulation);
    if (value == NULL) return emc_fail(c, fmi2Error, "fmi2GetRealStatus: value is NULL");
    if (s != fmi2LastSuccessfulTime)
        return emc_fail(c, fmi2Discard, "fmi2GetRealStatus: status kind %d is not provided (fmi2LastSuccessfulTime is)",
                        (int)s);
    *value = c->d->time;
    return fmi2OK;
}

/* fmi2Terminated: false (the FMU never asks to end the simulation after a step it discarded) */
fmi2Status fmi2GetBooleanStatus(fmi2Component component, const fmi2StatusKind s, fmi2Boolean *value)
{
    ENTER("fmi2GetBooleanStatus", M_STEP | M_TERMINATED);
    ONLY("fmi2GetBooleanStatus", fmi2CoSimulation);
    if (value == NULL) return emc_fail(c, fmi2Error, "fmi2GetBooleanStatus: value is NULL");
    if (s != fmi2Terminated)
        return emc_fail(c, fmi2Discard, "fmi2GetBooleanStatus: status kind %d is not provided (fmi2Terminated is)", (int)s);
    *value = fmi2False;
    return fmi2OK;
}

/* ---- Model Exchange ----------------------------------------------------------------------------- */
fmi2Status fmi2EnterEventMode(fmi2Component component)
{
    ENTER("fmi2EnterEventMode", M_EVENT | M_CONTINUOUS);
    ONLY("fmi2EnterEventMode", fmi2ModelExchange);
    c->d->mode = M_EVENT;
    return fmi2OK;
}

fmi2Status fmi2NewDiscreteStates(fmi2Component component, fmi2EventInfo *eventInfo)
{
    ENTER("fmi2NewDiscreteStates", M_EVENT);
    ONLY("fmi2NewDiscreteStates", fmi2ModelExchange);
    if (eventInfo == NULL) return emc_fail(c, fmi2Error, "fmi2NewDiscreteStates: eventInfo is NULL");
    memset(eventInfo, 0, sizeof *eventInfo);
    return emc_new_discrete_states(c, c->d, eventInfo);
}

fmi2Status fmi2EnterContinuousTimeMode(fmi2Component component)
{
    ENTER("fmi2EnterContinuousTimeMode", M_EVENT);
    ONLY("fmi2EnterContinuousTimeMode", fmi2ModelExchange);
    c->d->mode = M_CONTINUOUS;
    return fmi2OK;
}

fmi2Status fmi2CompletedIntegratorStep(fmi2Component component, fmi2Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi2Boolean *enterEventMode, fmi2Boolean *terminateSimulation)
{
    ENTER("fmi2CompletedIntegratorStep", M_CONTINUOUS);
    ONLY("fmi2CompletedIntegratorStep", fmi2ModelExchange);
    (void)noSetFMUStatePriorToCurrentPoint;
    if (enterEventMode == NULL || terminateSimulation == NULL)
        return emc_fail(c, fmi2Error, "fmi2CompletedIntegratorStep: enterEventMode or terminateSimulation is NULL");
    *enterEventMode = fmi2False;
    *terminateSimulation = fmi2False;
    return fmi2OK;
}

fmi2Status fmi2SetTime(fmi2Component component, fmi2Real time)
{
    ENTER("fmi2SetTime", M_EVENT | M_CONTINUOUS);
    ONLY("fmi2SetTime", fmi2ModelExchange);
    if (!isfinite(time)) return emc_fail(c, fmi2Error, "fmi2SetTime: time = %g is not finite", time);
    c->d->time = time;
    return fmi2OK;
}

/* an array of `expected` entries: the count must match, the pointer may be NULL only for 0 entries */
static fmi2Status check_array(emc_instance *c, const char *function, const void *array, size_t n, size_t expected,
                              const char *what)
{
    if (n != expected || (n > 0 && array == NULL))
        return emc_fail(c, fmi2Error, "%s: %zu values for %zu %s (or the array is NULL)", function, n, expected, what);
    return fmi2OK;
}

fmi2Status fmi2SetContinuousStates(fmi2Component component, const fmi2Real x[], size_t nx)
{
    ENTER("fmi2SetContinuousStates", M_CONTINUOUS);
    ONLY("fmi2SetContinuousStates", fmi2ModelExchange);
    if (check_array(c, "fmi2SetContinuousStates", x, nx, EMC_STATE_COUNT, "states") != fmi2OK) return fmi2Error;
    if (nx == 0) return fmi2OK;
    if (!emc_all_finite(x, nx))
        return emc_fail(c, fmi2Error, "fmi2SetContinuousStates: not finite at t = %.9g s; the state is kept", c->d->time);
    emc_set_states(c->d, x);
    return fmi2OK;
}

fmi2Status fmi2GetDerivatives(fmi2Component component, fmi2Real derivatives[], size_t nx)
{
    ENTER("fmi2GetDerivatives", M_EVENT | M_CONTINUOUS | M_TERMINATED);
    ONLY("fmi2GetDerivatives", fmi2ModelExchange);
    if (check_array(c, "fmi2GetDerivatives", derivatives, nx, EMC_STATE_COUNT, "states") != fmi2OK) return fmi2Error;
    return nx == 0 ? fmi2OK : emc_derivatives(c, c->d, derivatives);
}

fmi2Status fmi2GetEventIndicators(fmi2Component component, fmi2Real eventIndicators[], size_t ni)
{
    ENTER("fmi2GetEventIndicators", M_INITIALIZATION | M_EVENT | M_CONTINUOUS | M_TERMINATED);
    ONLY("fmi2GetEventIndicators", fmi2ModelExchange);
    if (check_array(c, "fmi2GetEventIndicators", eventIndicators, ni, EMC_EVENT_INDICATOR_COUNT, "event indicators")
        != fmi2OK)
        return fmi2Error;
    return ni == 0 ? fmi2OK : emc_event_indicators(c, c->d, eventIndicators);
}

fmi2Status fmi2GetContinuousStates(fmi2Component component, fmi2Real x[], size_t nx)
{
    ENTER("fmi2GetContinuousStates", M_INITIALIZATION | M_EVENT | M_CONTINUOUS | M_TERMINATED);
    ONLY("fmi2GetContinuousStates", fmi2ModelExchange);
    if (check_array(c, "fmi2GetContinuousStates", x, nx, EMC_STATE_COUNT, "states") != fmi2OK) return fmi2Error;
    if (nx > 0) emc_get_states(c->d, x);
    return fmi2OK;
}

fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component component, fmi2Real x_nominal[], size_t nx)
{
    ENTER("fmi2GetNominalsOfContinuousStates", M_INSTANTIATED | M_EVENT | M_CONTINUOUS | M_TERMINATED);
    ONLY("fmi2GetNominalsOfContinuousStates", fmi2ModelExchange);
    if (check_array(c, "fmi2GetNominalsOfContinuousStates", x_nominal, nx, EMC_STATE_COUNT, "states") != fmi2OK)
        return fmi2Error;
    return nx == 0 ? fmi2OK : emc_nominals(c, c->d, x_nominal);
}
