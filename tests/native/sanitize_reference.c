/* A C host for the native Reference FMU's sources under AddressSanitizer and UndefinedBehaviorSanitizer
 * (tests/test_native_sanitizers.py): both interfaces legally and the illegal calls of both state machines,
 * bad kinds and parameters, NULL and out-of-range arguments, a full FMU-state pool, a corrupt serialized state.
 * Each call's status is compared with what FMI 2.0 and docs/native-fmus.md ask; the exit status is the number
 * of mismatches. Linked with the sources (no dlopen). */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#include "fmi2Functions.h"
#include "emc_reference.h"

static int failures = 0;
static int messages = 0;

static void logger(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status, fmi2String category,
                   fmi2String message, ...)
{
    va_list args;
    (void)env; (void)name; (void)status; (void)category;
    va_start(args, message);
    vfprintf(stdout, message, args);
    va_end(args);
    fputc('\n', stdout);
    messages++;
}

#define EXPECT(call, status)                                                                   \
    do {                                                                                       \
        fmi2Status got_ = (call);                                                              \
        if (got_ != (status)) {                                                                \
            fprintf(stderr, "line %d: %s gave %d, expected %d\n", __LINE__, #call, (int)got_, (int)(status)); \
            failures++;                                                                        \
        }                                                                                      \
    } while (0)

static const fmi2CallbackFunctions callbacks = {logger, NULL, NULL, NULL, NULL};

static fmi2ValueReference vr_of(const char *name)
{
    int i;
    for (i = 0; i < EMC_N_VARIABLES; i++)
        if (strcmp(EMC_VARIABLES[i].name, name) == 0) return (fmi2ValueReference)i;
    fprintf(stderr, "no variable %s\n", name);
    failures++;
    return 0;
}

static void run(fmi2Type type)
{
    fmi2Component c = fmi2Instantiate("r", type, EMC_GUID, NULL, &callbacks, fmi2False, fmi2False);
    fmi2ValueReference kind[1], jet[4], amplitude[1], bad[1] = {99999};
    fmi2Integer value_kind[1], orders[4] = {1, 2, 3, 4};
    fmi2Real value[4], one[1] = {NAN};
    fmi2FMUstate states[9] = {NULL};
    fmi2Byte buffer[4096];
    fmi2EventInfo info;
    size_t size = 0;
    double t = 0.0;
    int i;
    if (c == NULL) { failures++; return; }
    kind[0] = vr_of("kind");
    amplitude[0] = vr_of("amplitude");
    jet[0] = vr_of("q_star"); jet[1] = vr_of("q_star_dot"); jet[2] = vr_of("q_star_ddot"); jet[3] = vr_of("q_star_dddot");
    EXPECT(fmi2GetReal(c, jet, 4, value), fmi2Error);                      /* before initialization */
    EXPECT(fmi2DoStep(c, 0.0, 0.1, fmi2True), fmi2Error);
    EXPECT(fmi2SetReal(c, bad, 1, value), fmi2Error);
    EXPECT(fmi2SetReal(c, jet, 1, value), fmi2Error);                      /* an output */
    EXPECT(fmi2SetReal(c, amplitude, 1, one), fmi2Error);                  /* not finite */
    EXPECT(fmi2SetReal(c, kind, 1, value), fmi2Error);                     /* an Integer */
    EXPECT(fmi2SetInteger(c, amplitude, 1, value_kind), fmi2Error);        /* a Real */
    EXPECT(fmi2SetInteger(c, NULL, 1, value_kind), fmi2Error);
    value_kind[0] = 7;
    EXPECT(fmi2SetInteger(c, kind, 1, value_kind), fmi2OK);                /* checked at exit */
    EXPECT(fmi2SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0), fmi2OK);
    EXPECT(fmi2EnterInitializationMode(c), fmi2OK);
    EXPECT(fmi2ExitInitializationMode(c), fmi2Error);                      /* kind 7 */
    value_kind[0] = 1;                                                     /* the sinusoid */
    EXPECT(fmi2SetInteger(c, kind, 1, value_kind), fmi2OK);
    EXPECT(fmi2GetReal(c, jet, 4, value), fmi2OK);
    EXPECT(fmi2ExitInitializationMode(c), fmi2OK);
    EXPECT(fmi2SetInteger(c, kind, 1, value_kind), fmi2Error);             /* fixed after initialization */
    EXPECT(fmi2GetInteger(c, kind, 1, value_kind), fmi2OK);
    EXPECT(fmi2GetDirectionalDerivative(c, jet, 1, jet, 1, value, value), fmi2Error);   /* not provided */
    for (i = 0; i < 8; i++) EXPECT(fmi2GetFMUstate(c, &states[i]), fmi2OK);
    EXPECT(fmi2GetFMUstate(c, &states[8]), fmi2Error);                     /* the pool is full */
    EXPECT(fmi2SerializedFMUstateSize(c, states[0], &size), fmi2OK);
    if (size > sizeof buffer) { failures++; return; }
    EXPECT(fmi2SerializeFMUstate(c, states[0], buffer, size), fmi2OK);
    EXPECT(fmi2FreeFMUstate(c, &states[1]), fmi2OK);
    EXPECT(fmi2DeSerializeFMUstate(c, buffer, size, &states[1]), fmi2OK);
    buffer[size - 2] = (fmi2Byte)0xff;                                     /* corrupt: refused or still valid */
    buffer[size / 2] ^= 0x55;
    (void)fmi2DeSerializeFMUstate(c, buffer, size, &states[2]);
    EXPECT(fmi2DeSerializeFMUstate(c, buffer, 1, &states[2]), fmi2Error);
    EXPECT(fmi2SetFMUstate(c, (fmi2FMUstate)buffer), fmi2Error);           /* not one of the instance's */
    EXPECT(fmi2SetFMUstate(c, states[0]), fmi2OK);
    for (i = 0; i < 8; i++) EXPECT(fmi2FreeFMUstate(c, &states[i]), fmi2OK);
    if (type == fmi2CoSimulation) {
        for (i = 0; i < 100; i++) {
            EXPECT(fmi2DoStep(c, t, 1e-3, fmi2True), fmi2OK);
            t += 1e-3;
            EXPECT(fmi2GetReal(c, jet, 4, value), fmi2OK);
            EXPECT(fmi2GetRealOutputDerivatives(c, jet, 3, orders, value), fmi2OK);
        }
        EXPECT(fmi2GetRealOutputDerivatives(c, jet, 4, orders, value), fmi2Error);   /* order 4 */
        EXPECT(fmi2GetRealOutputDerivatives(c, jet, 1, NULL, value), fmi2Error);
        EXPECT(fmi2SetRealInputDerivatives(c, jet, 1, orders, value), fmi2Error);    /* no inputs */
        EXPECT(fmi2DoStep(c, t + 1.0, 1e-3, fmi2True), fmi2Error);                   /* not the FMU's time */
        EXPECT(fmi2DoStep(c, t, -1e-3, fmi2True), fmi2Error);
        EXPECT(fmi2EnterEventMode(c), fmi2Error);
        EXPECT(fmi2GetDerivatives(c, value, 0), fmi2Error);
    } else {
        EXPECT(fmi2NewDiscreteStates(c, &info), fmi2OK);
        EXPECT(fmi2EnterContinuousTimeMode(c), fmi2OK);
        EXPECT(fmi2SetContinuousStates(c, NULL, 0), fmi2OK);
        EXPECT(fmi2SetContinuousStates(c, value, 1), fmi2Error);
        EXPECT(fmi2GetEventIndicators(c, NULL, 0), fmi2OK);
        for (i = 0; i < 100; i++) {
            EXPECT(fmi2SetTime(c, i * 1e-3), fmi2OK);
            EXPECT(fmi2GetReal(c, jet, 4, value), fmi2OK);
        }
        EXPECT(fmi2SetTime(c, NAN), fmi2Error);
        EXPECT(fmi2DoStep(c, 0.0, 0.1, fmi2True), fmi2Error);
        EXPECT(fmi2GetRealOutputDerivatives(c, jet, 1, orders, value), fmi2Error);   /* a CS function */
        EXPECT(fmi2EnterEventMode(c), fmi2OK);
    }
    EXPECT(fmi2Terminate(c), fmi2OK);
    EXPECT(fmi2Terminate(c), fmi2Error);
    EXPECT(fmi2Reset(c), fmi2OK);
    EXPECT(fmi2GetReal(c, jet, 4, value), fmi2Error);                      /* instantiated again */
    fmi2FreeInstance(c);
}

int main(void)
{
    run(fmi2ModelExchange);
    run(fmi2CoSimulation);
    if (messages == 0) failures++;
    fprintf(stderr, "%d mismatches\n", failures);
    return failures;
}
