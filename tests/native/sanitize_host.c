/* A C host for a native plant FMU's sources, built with AddressSanitizer and UndefinedBehaviorSanitizer
 * (tests/test_native_sanitizers.py): legal runs of both interfaces and the illegal calls of both state
 * machines, NULL and out-of-range arguments, non-finite values, a full FMU-state pool, a corrupt
 * serialized state. Each call's status is compared with what FMI 2.0 and docs/native-fmus.md ask;
 * the exit status is the number of mismatches. Linked with the sources (no dlopen). */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#include "fmi2Functions.h"
#include "emc_framework.h"

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

#define CHECK(condition)                                                                       \
    do {                                                                                       \
        if (!(condition)) { fprintf(stderr, "line %d: %s is false\n", __LINE__, #condition); failures++; } \
    } while (0)

static const fmi2CallbackFunctions callbacks = {logger, NULL, NULL, NULL, NULL};

/* value references of the plant FMUs: the pythonfmu twin's layout (parameters, x_0, rtol, u, q, p, x_e, H, der) */
static fmi2ValueReference vr_of(fmi2Component c, const char *name);

static void model_exchange(void)
{
    fmi2Component c;
    fmi2Real x[3], dx[3], z[1], nominal[3], value[4];
    fmi2ValueReference vr[1] = {0}, bad_vr[1] = {100000};
    fmi2EventInfo info;
    fmi2FMUstate states[9] = {NULL};
    fmi2Boolean enter, terminate;
    fmi2Byte buffer[4096];
    size_t size = 0;
    int i;
    const double nan = NAN;

    CHECK(fmi2Instantiate("me", fmi2ModelExchange, EMC_GUID, "", NULL, fmi2False, fmi2False) == NULL);
    CHECK(fmi2Instantiate("me", fmi2ModelExchange, "{wrong}", "", &callbacks, fmi2False, fmi2False) == NULL);
    /* a '%' in a message's text reaches this (formatting) logger as a literal '%' (emc_fmi2.c, log_to) */
    CHECK(fmi2Instantiate("me", fmi2ModelExchange, "{50%n%s}", "", &callbacks, fmi2False, fmi2False) == NULL);
    CHECK(fmi2Instantiate("me", (fmi2Type)7, EMC_GUID, "", &callbacks, fmi2False, fmi2False) == NULL);
    CHECK(fmi2Instantiate(NULL, fmi2ModelExchange, EMC_GUID, "", &callbacks, fmi2False, fmi2False) == NULL);
    c = fmi2Instantiate("me", fmi2ModelExchange, EMC_GUID, NULL, &callbacks, fmi2False, fmi2True);
    CHECK(c != NULL);
    if (c == NULL) return;
    EXPECT(fmi2SetTime(NULL, 0.0), fmi2Error);
    EXPECT(fmi2SetTime(c, 0.0), fmi2Error);                            /* before initialization */
    EXPECT(fmi2SetContinuousStates(c, x, 3), fmi2Error);
    EXPECT(fmi2GetDerivatives(c, dx, 3), fmi2Error);
    EXPECT(fmi2EnterEventMode(c), fmi2Error);
    EXPECT(fmi2NewDiscreteStates(c, &info), fmi2Error);
    EXPECT(fmi2GetReal(c, vr, 1, value), fmi2Error);
    EXPECT(fmi2DoStep(c, 0.0, 1e-3, fmi2True), fmi2Error);             /* a CS function */
    EXPECT(fmi2SetReal(c, NULL, 1, value), fmi2Error);
    EXPECT(fmi2SetReal(c, vr, 1, NULL), fmi2Error);
    EXPECT(fmi2SetReal(c, bad_vr, 1, value), fmi2Error);
    EXPECT(fmi2SetReal(c, vr, 1, &nan), fmi2Error);
    EXPECT(fmi2SetReal(c, vr, 0, NULL), fmi2OK);
    EXPECT(fmi2SetInteger(c, vr, 1, NULL), fmi2Error);
    EXPECT(fmi2SetDebugLogging(c, fmi2True, 1, NULL), fmi2Error);
    EXPECT(fmi2GetNominalsOfContinuousStates(c, nominal, 3), fmi2OK);
    EXPECT(fmi2GetNominalsOfContinuousStates(c, NULL, 3), fmi2Error);
    EXPECT(fmi2SetupExperiment(c, fmi2True, -1.0, 0.0, fmi2False, 0.0), fmi2Error);
    EXPECT(fmi2SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2True, 1.0), fmi2OK);
    EXPECT(fmi2EnterInitializationMode(c), fmi2OK);
    EXPECT(fmi2GetEventIndicators(c, z, 1), fmi2OK);
    EXPECT(fmi2GetEventIndicators(c, z, 2), fmi2Error);
    EXPECT(fmi2ExitInitializationMode(c), fmi2OK);
    EXPECT(fmi2ExitInitializationMode(c), fmi2Error);                  /* twice */
    EXPECT(fmi2SetContinuousStates(c, x, 3), fmi2Error);               /* event mode */
    EXPECT(fmi2NewDiscreteStates(c, NULL), fmi2Error);
    EXPECT(fmi2NewDiscreteStates(c, &info), fmi2OK);
    EXPECT(fmi2EnterContinuousTimeMode(c), fmi2OK);
    EXPECT(fmi2GetContinuousStates(c, x, 3), fmi2OK);
    EXPECT(fmi2GetContinuousStates(c, x, 2), fmi2Error);
    for (i = 0; i < 100; i++) {                      /* a forward-Euler run, stable for both plants */
        EXPECT(fmi2SetTime(c, i * 1e-11), fmi2OK);
        EXPECT(fmi2GetDerivatives(c, dx, 3), fmi2OK);
        x[0] += 1e-11 * dx[0]; x[1] += 1e-11 * dx[1]; x[2] += 1e-11 * dx[2];
        EXPECT(fmi2SetContinuousStates(c, x, 3), fmi2OK);
        EXPECT(fmi2CompletedIntegratorStep(c, fmi2True, &enter, &terminate), fmi2OK);
    }
    EXPECT(fmi2CompletedIntegratorStep(c, fmi2True, NULL, &terminate), fmi2Error);
    EXPECT(fmi2SetTime(c, NAN), fmi2Error);
    x[1] = NAN;
    EXPECT(fmi2SetContinuousStates(c, x, 3), fmi2Error);
    EXPECT(fmi2SetContinuousStates(c, NULL, 3), fmi2Error);
    for (i = 0; i < 8; i++) EXPECT(fmi2GetFMUstate(c, &states[i]), fmi2OK);
    EXPECT(fmi2GetFMUstate(c, &states[8]), fmi2Error);                 /* the pool is full */
    EXPECT(fmi2GetFMUstate(c, NULL), fmi2Error);
    EXPECT(fmi2SerializedFMUstateSize(c, states[0], &size), fmi2OK);
    CHECK(size > 0 && size <= sizeof buffer);
    EXPECT(fmi2SerializeFMUstate(c, states[0], buffer, size), fmi2OK);
    EXPECT(fmi2SerializeFMUstate(c, states[0], buffer, size - 1), fmi2Error);
    EXPECT(fmi2FreeFMUstate(c, &states[1]), fmi2OK);
    EXPECT(fmi2DeSerializeFMUstate(c, buffer, size, &states[1]), fmi2OK);
    buffer[size - 1] ^= 0x7f;                                           /* corrupt: refused or still valid */
    buffer[size / 2] = (fmi2Byte)0xff;
    (void)fmi2DeSerializeFMUstate(c, buffer, size, &states[2]);
    EXPECT(fmi2DeSerializeFMUstate(c, buffer, 3, &states[2]), fmi2Error);
    EXPECT(fmi2DeSerializeFMUstate(c, NULL, size, &states[2]), fmi2Error);
    EXPECT(fmi2SetFMUstate(c, (fmi2FMUstate)buffer), fmi2Error);       /* not one of the instance's */
    EXPECT(fmi2SetFMUstate(c, states[1]), fmi2OK);
    for (i = 0; i < 8; i++) EXPECT(fmi2FreeFMUstate(c, &states[i]), fmi2OK);
    {
        fmi2ValueReference knowns[1] = {vr_of(c, "q")}, unknowns[1] = {vr_of(c, "der(p)")};
        fmi2Real seed[1] = {1.0}, out[1];
        EXPECT(fmi2GetDirectionalDerivative(c, unknowns, 1, knowns, 1, seed, out), fmi2OK);
        EXPECT(fmi2GetDirectionalDerivative(c, knowns, 1, unknowns, 1, seed, out), fmi2Error);
        EXPECT(fmi2GetDirectionalDerivative(c, unknowns, 1, knowns, 1, NULL, out), fmi2Error);
    }
    EXPECT(fmi2EnterEventMode(c), fmi2OK);
    EXPECT(fmi2Terminate(c), fmi2OK);
    EXPECT(fmi2Terminate(c), fmi2Error);
    EXPECT(fmi2GetDerivatives(c, dx, 3), fmi2OK);                      /* allowed after fmi2Terminate */
    EXPECT(fmi2Reset(c), fmi2OK);
    EXPECT(fmi2SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0), fmi2OK);
    fmi2FreeInstance(c);
    fmi2FreeInstance(NULL);
}

static fmi2ValueReference vr_of(fmi2Component c, const char *name)
{
    /* a host finds value references in modelDescription.xml; this test by name in the sources' table */
    int i;
    (void)c;
    for (i = 0; i < EMC_N_VARIABLES; i++)
        if (strcmp(EMC_VARIABLES[i].name, name) == 0) return (fmi2ValueReference)i;
    fprintf(stderr, "no variable %s\n", name);
    failures++;
    return 0;
}

static void co_simulation(void)
{
    fmi2Component c = fmi2Instantiate("cs", fmi2CoSimulation, EMC_GUID, NULL, &callbacks, fmi2False, fmi2False);
    fmi2ValueReference u[1], outs[4], rtol[1];
    fmi2Integer orders[3] = {1, 2, 3}, two[4] = {2, 2, 2, 2}, zero[1] = {0};
    fmi2ValueReference us[3];
    fmi2Real rates[3] = {1.0, -2.0, 3.0}, value[4], big[1] = {1e300}, one[1] = {1.0};
    fmi2FMUstate s = NULL;
    double t = 0.0;
    int i;
    CHECK(c != NULL);
    if (c == NULL) return;
    u[0] = vr_of(c, "u");
    rtol[0] = vr_of(c, "rtol");
    us[0] = us[1] = us[2] = u[0];
    outs[0] = vr_of(c, "q"); outs[1] = vr_of(c, "p"); outs[2] = vr_of(c, "x_e"); outs[3] = vr_of(c, "H");
    EXPECT(fmi2DoStep(c, 0.0, 1e-3, fmi2True), fmi2Error);             /* before initialization */
    EXPECT(fmi2GetDerivatives(c, value, 3), fmi2Error);                /* an ME function */
    EXPECT(fmi2SetupExperiment(c, fmi2True, 1e-6, 0.0, fmi2False, 0.0), fmi2OK);
    EXPECT(fmi2EnterInitializationMode(c), fmi2OK);
    EXPECT(fmi2SetReal(c, rtol, 1, one), fmi2OK);                      /* rtol = 1 is outside [1e-14, 1e-2] */
    EXPECT(fmi2ExitInitializationMode(c), fmi2Error);
    one[0] = 1e-8;
    EXPECT(fmi2SetReal(c, rtol, 1, one), fmi2OK);
    EXPECT(fmi2ExitInitializationMode(c), fmi2OK);
    for (i = 0; i < 50; i++) {
        EXPECT(fmi2SetRealInputDerivatives(c, us, 3, orders, rates), fmi2OK);
        EXPECT(fmi2DoStep(c, t, 1e-5, fmi2True), fmi2OK);
        t += 1e-5;
        EXPECT(fmi2GetReal(c, outs, 4, value), fmi2OK);
        EXPECT(fmi2GetRealOutputDerivatives(c, outs, 4, two, value), fmi2OK);
    }
    EXPECT(fmi2SetRealInputDerivatives(c, us, 1, zero, rates), fmi2Error);
    EXPECT(fmi2SetRealInputDerivatives(c, outs, 1, orders, rates), fmi2Error);
    EXPECT(fmi2SetRealInputDerivatives(c, us, 1, NULL, rates), fmi2Error);
    EXPECT(fmi2GetRealOutputDerivatives(c, outs, 1, orders + 2, value), fmi2Error);
    EXPECT(fmi2DoStep(c, t + 1.0, 1e-5, fmi2True), fmi2Error);         /* not the FMU's time */
    EXPECT(fmi2DoStep(c, t, -1e-5, fmi2True), fmi2Error);
    EXPECT(fmi2DoStep(c, t, NAN, fmi2True), fmi2Error);
    EXPECT(fmi2GetFMUstate(c, &s), fmi2OK);
    EXPECT(fmi2SetRealInputDerivatives(c, us + 2, 1, orders + 2, big), fmi2OK);
    EXPECT(fmi2DoStep(c, t, 1e3, fmi2True), fmi2Discard);              /* the polynomial overflows */
    EXPECT(fmi2SetFMUstate(c, s), fmi2OK);
    EXPECT(fmi2FreeFMUstate(c, &s), fmi2OK);
    {
        fmi2Real last = -1.0;
        fmi2Boolean terminated = fmi2True;
        EXPECT(fmi2GetRealStatus(c, fmi2LastSuccessfulTime, &last), fmi2OK);
        CHECK(last == t);
        EXPECT(fmi2GetBooleanStatus(c, fmi2Terminated, &terminated), fmi2OK);
        CHECK(terminated == fmi2False);
        EXPECT(fmi2GetBooleanStatus(c, fmi2Terminated, NULL), fmi2Error);
        EXPECT(fmi2GetRealStatus(c, fmi2DoStepStatus, &last), fmi2Discard);
    }
    EXPECT(fmi2CancelStep(c), fmi2Error);
    EXPECT(fmi2EnterEventMode(c), fmi2Error);
    EXPECT(fmi2Terminate(c), fmi2OK);
    EXPECT(fmi2DoStep(c, t, 1e-5, fmi2True), fmi2Error);
    fmi2FreeInstance(c);
}

int main(void)
{
    model_exchange();
    co_simulation();
    CHECK(messages > 0);
    fprintf(stderr, "%d mismatches\n", failures);
    return failures;
}
