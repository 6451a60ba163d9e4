/* A C host for a native controller FMU's sources under AddressSanitizer and UndefinedBehaviorSanitizer
 * (tests/test_native_sanitizers.py): both interfaces legally, then the illegal calls, NULL and out-of-range
 * arguments, NaN inputs, an infeasible reference, a full FMU-state pool and a corrupted serialized state; the
 * design's conditions (emc_ctrl_design, where EMC_DESIGN_CHECKED) with the parameter argv[1] set to argv[2], a
 * value that violates one: refused with strict = 1, warned with strict = 0; without them strict = 1 is refused.
 * The exit status is the number of mismatches. Linked with the sources (no dlopen). */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "emc_controller.h"

static int failures = 0;

static void logger(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status, fmi2String category,
                   fmi2String message, ...)
{
    va_list args;
    (void)env; (void)name; (void)status; (void)category;
    va_start(args, message);
    vfprintf(stdout, message, args);
    va_end(args);
    fputc('\n', stdout);
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

static const char *broken_name;             /* a parameter, and a value of it that violates a design condition */
static double broken_value;

/* the first output (u, or u_1 of a device with n_e > 1) */
static fmi2ValueReference first_output(void)
{
    int i;
    for (i = 0; i < EMC_N_VARIABLES; i++)
        if (EMC_VARIABLES[i].kind == EMC_C_OUTPUT) return (fmi2ValueReference)i;
    failures++;
    return 0;
}

/* the index of the first reference position q_i* among the inputs (after q, p, x_e) */
static int first_reference_input(void)
{
    int i;
    for (i = 0; i < EMC_N_CONTROLLER_INPUTS; i++) {
        size_t n = strlen(EMC_INPUT_NAMES[i]);
        if (n > 5 && strcmp(EMC_INPUT_NAMES[i] + n - 5, "_star") == 0) return i;
    }
    failures++;
    return 0;
}

static void run(fmi2Type type)
{
    fmi2Component c = fmi2Instantiate("c", type, EMC_GUID, NULL, &callbacks, fmi2False, fmi2False);
    fmi2ValueReference u[1], ins[EMC_N_CONTROLLER_INPUTS], strict[1], bad[1] = {9999}, broken[1];
    fmi2Real value[EMC_N_CONTROLLER_INPUTS], one[1], seeds[EMC_N_CONTROLLER_INPUTS];
    fmi2Integer orders[EMC_N_CONTROLLER_INPUTS], flag[1] = {1};
    fmi2FMUstate states[9] = {NULL};
    fmi2Byte buffer[8192];
    fmi2EventInfo info;
    size_t size = 0;
    int i;
    if (c == NULL) { failures++; return; }
    u[0] = first_output();
    strict[0] = vr_of("strict");
#if EMC_DESIGN_CHECKED
    broken[0] = vr_of(broken_name);
#else
    (void)broken;
#endif
    for (i = 0; i < EMC_N_CONTROLLER_INPUTS; i++) {
        ins[i] = vr_of(EMC_INPUT_NAMES[i]);
        orders[i] = 1 + i % 3;
        seeds[i] = 1.0 + i;
    }
    EXPECT(fmi2GetReal(c, u, 1, one), fmi2Error);                          /* before initialization */
    EXPECT(fmi2DoStep(c, 0.0, 0.1, fmi2True), fmi2Error);
    EXPECT(fmi2SetReal(c, bad, 1, one), fmi2Error);
    EXPECT(fmi2SetReal(c, u, 1, one), fmi2Error);                          /* an output */
    EXPECT(fmi2SetReal(c, NULL, 1, one), fmi2Error);
    EXPECT(fmi2SetInteger(c, strict, 1, flag), fmi2OK);
    EXPECT(fmi2SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0), fmi2OK);
    EXPECT(fmi2EnterInitializationMode(c), fmi2OK);
#if EMC_DESIGN_CHECKED
    EXPECT(fmi2ExitInitializationMode(c), fmi2OK);                         /* strict = 1: the conditions hold */
    EXPECT(fmi2Reset(c), fmi2OK);
    EXPECT(fmi2SetInteger(c, strict, 1, flag), fmi2OK);
    EXPECT(fmi2SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0), fmi2OK);
    EXPECT(fmi2EnterInitializationMode(c), fmi2OK);
    EXPECT(fmi2SetReal(c, broken, 1, &broken_value), fmi2OK);
    EXPECT(fmi2ExitInitializationMode(c), fmi2Error);                      /* strict = 1: one is violated */
#else
    EXPECT(fmi2ExitInitializationMode(c), fmi2Error);                      /* strict = 1: not provided natively */
#endif
    flag[0] = 0;
    EXPECT(fmi2SetInteger(c, strict, 1, flag), fmi2OK);
    EXPECT(fmi2SetInteger(c, u, 1, flag), fmi2Error);
    EXPECT(fmi2GetReal(c, u, 1, one), fmi2OK);
    EXPECT(fmi2ExitInitializationMode(c), fmi2OK);                         /* strict = 0: a warning */
    EXPECT(fmi2GetReal(c, ins, EMC_N_CONTROLLER_INPUTS, value), fmi2OK);
    EXPECT(fmi2GetDirectionalDerivative(c, u, 1, ins, EMC_N_CONTROLLER_INPUTS, seeds, one), fmi2OK);
    EXPECT(fmi2GetDirectionalDerivative(c, ins, 1, u, 1, seeds, one), fmi2Error);
    for (i = 0; i < 8; i++) EXPECT(fmi2GetFMUstate(c, &states[i]), fmi2OK);
    EXPECT(fmi2GetFMUstate(c, &states[8]), fmi2Error);
    EXPECT(fmi2SerializedFMUstateSize(c, states[0], &size), fmi2OK);
    if (size > sizeof buffer) { failures++; return; }
    EXPECT(fmi2SerializeFMUstate(c, states[0], buffer, size), fmi2OK);
    buffer[size - 3] = (fmi2Byte)0xff;
    buffer[size / 2] ^= 0x55;
    (void)fmi2DeSerializeFMUstate(c, buffer, size, &states[1]);
    EXPECT(fmi2DeSerializeFMUstate(c, buffer, 2, &states[1]), fmi2Error);
    for (i = 0; i < 8; i++) EXPECT(fmi2FreeFMUstate(c, &states[i]), fmi2OK);
    if (type == fmi2CoSimulation) {
        EXPECT(fmi2SetRealInputDerivatives(c, ins, EMC_N_CONTROLLER_INPUTS, orders, seeds), fmi2OK);
        orders[0] = 1;
        EXPECT(fmi2GetRealOutputDerivatives(c, u, 1, orders, one), fmi2OK);
        orders[0] = 2;
        EXPECT(fmi2GetRealOutputDerivatives(c, u, 1, orders, one), fmi2Error);
        orders[0] = 0;
        EXPECT(fmi2SetRealInputDerivatives(c, ins, 1, orders, seeds), fmi2Error);
        EXPECT(fmi2SetRealInputDerivatives(c, ins, 1, NULL, seeds), fmi2Error);
        EXPECT(fmi2DoStep(c, 0.0, 0.1, fmi2True), fmi2OK);
        EXPECT(fmi2DoStep(c, 5.0, 0.1, fmi2True), fmi2Error);             /* not the FMU's time */
        one[0] = NAN;
        EXPECT(fmi2SetReal(c, ins, 1, one), fmi2Error);
        one[0] = -1.0;                                                     /* q far outside the domain */
        EXPECT(fmi2SetReal(c, ins, 1, one), fmi2OK);
        if (EMC_TRACKING) {
            one[0] = 1e3;                                                  /* q* too: not feasible */
            EXPECT(fmi2SetReal(c, ins + first_reference_input(), 1, one), fmi2OK);
            EXPECT(fmi2DoStep(c, 0.1, 0.1, fmi2True), fmi2Discard);
            EXPECT(fmi2GetReal(c, u, 1, one), fmi2Error);
        }
        EXPECT(fmi2EnterEventMode(c), fmi2Error);
        EXPECT(fmi2GetDerivatives(c, value, 0), fmi2Error);
    } else {
        EXPECT(fmi2NewDiscreteStates(c, &info), fmi2OK);
        EXPECT(fmi2EnterContinuousTimeMode(c), fmi2OK);
        EXPECT(fmi2SetContinuousStates(c, NULL, 0), fmi2OK);
        EXPECT(fmi2SetContinuousStates(c, value, 1), fmi2Error);
        EXPECT(fmi2GetDerivatives(c, NULL, 0), fmi2OK);
        EXPECT(fmi2SetTime(c, 0.5), fmi2OK);
        EXPECT(fmi2GetReal(c, u, 1, one), fmi2OK);
        EXPECT(fmi2DoStep(c, 0.0, 0.1, fmi2True), fmi2Error);
        EXPECT(fmi2SetRealInputDerivatives(c, ins, 1, orders, seeds), fmi2Error);
        EXPECT(fmi2EnterEventMode(c), fmi2OK);
    }
    EXPECT(fmi2Terminate(c), fmi2OK);
    EXPECT(fmi2Terminate(c), fmi2Error);
    fmi2FreeInstance(c);
}

int main(int argc, char **argv)
{
    if (argc != (EMC_DESIGN_CHECKED ? 3 : 1)) {
        fprintf(stderr, EMC_DESIGN_CHECKED ? "usage: host PARAMETER VALUE (a value that violates a design condition)\n"
                                           : "usage: host (this controller has no native design checks)\n");
        return 1;
    }
    if (argc == 3) {
        broken_name = argv[1];
        broken_value = strtod(argv[2], NULL);
    }
    run(fmi2ModelExchange);
    run(fmi2CoSimulation);
    fprintf(stderr, "%d mismatches\n", failures);
    return failures;
}
