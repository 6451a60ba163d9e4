/* A C host for a native plant FMU's sources that counts every allocation of the process
 * (tests/test_native_realtime.py): it replaces malloc, calloc, realloc and free (glibc lets a program do so,
 * and then its own calls go here too) by a bump allocator with a counter, and checks that after
 * fmi2Instantiate nothing allocates: a Co-Simulation run with input polynomials, outputs, output derivatives
 * and FMU states (get, set, serialize, deserialize), a Model Exchange run, directional derivatives, and the
 * refusals of bad calls (with a logger: their messages are formatted). Prints "<n> allocations after
 * instantiation" and "<m> mismatches"; nothing is printed between the counts. Linked with the sources. */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "emc_framework.h"

/* ---- the allocator: a static arena, 16-byte aligned blocks with their size in front --------------------- */
static unsigned char arena[1 << 24];
static size_t used = 0;
static long allocations = 0;

void *malloc(size_t n)
{
    size_t need = (n + 15) / 16 * 16 + 16;
    unsigned char *block;
    if (used + need > sizeof arena) return NULL;
    block = arena + used;
    used += need;
    allocations++;
    memcpy(block, &n, sizeof n);
    return block + 16;
}

void free(void *p) { (void)p; }

void *calloc(size_t count, size_t size)
{
    void *p;
    if (size != 0 && count > (size_t)-1 / size) return NULL;
    p = malloc(count * size);
    if (p != NULL) memset(p, 0, count * size);
    return p;
}

void *realloc(void *p, size_t n)
{
    size_t old;
    void *q;
    if (p == NULL) return malloc(n);
    memcpy(&old, (unsigned char *)p - 16, sizeof old);
    q = malloc(n);
    if (q != NULL) memcpy(q, p, old < n ? old : n);
    return q;
}

/* ---- the host ---------------------------------------------------------------------------------------- */
static int failures = 0;
static char last[1024];

static void logger(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status, fmi2String category,
                   fmi2String message, ...)
{
    va_list args;
    (void)env; (void)name; (void)status; (void)category;
    va_start(args, message);
    vsnprintf(last, sizeof last, message, args);      /* formatted, as a host does, but not printed */
    va_end(args);
}

static const fmi2CallbackFunctions callbacks = {logger, NULL, NULL, NULL, NULL};

#define EXPECT(call, status) do { if ((call) != (status)) failures++; } while (0)

static fmi2ValueReference vr_of(const char *name)
{
    int i;
    for (i = 0; i < EMC_N_VARIABLES; i++)
        if (strcmp(EMC_VARIABLES[i].name, name) == 0) return (fmi2ValueReference)i;
    failures++;
    return 0;
}

static fmi2Byte blob[1 << 16];

int main(void)
{
    fmi2Component cs = fmi2Instantiate("cs", fmi2CoSimulation, EMC_GUID, NULL, &callbacks, fmi2False, fmi2False);
    fmi2Component me = fmi2Instantiate("me", fmi2ModelExchange, EMC_GUID, NULL, &callbacks, fmi2False, fmi2False);
    fmi2ValueReference u[1], us[3], outs[4], der[1], q[1], bad[1] = {99999};
    fmi2Integer orders[3] = {1, 2, 3}, two[4] = {2, 2, 2, 2};
    fmi2Real value[4], rates[3], x[EMC_N_STATES], dx[EMC_N_STATES], z[1], seed[1] = {1.0}, nan[1] = {NAN};
    fmi2FMUstate s = NULL, t = NULL;
    fmi2EventInfo info;
    fmi2Boolean enter, stop;
    size_t size = 0;
    long before;
    double time = 0.0, u0;
    int k, i;
    if (cs == NULL || me == NULL) return 1;
    u[0] = vr_of("u");
    us[0] = us[1] = us[2] = u[0];
    outs[0] = vr_of("q"); outs[1] = vr_of("p"); outs[2] = vr_of("x_e"); outs[3] = vr_of("H");
    der[0] = vr_of("der(p)");
    q[0] = vr_of("q");
    before = allocations;
    /* Co-Simulation: 500 steps of 1e-5 s with order-3 input polynomials around the start value of u */
    EXPECT(fmi2SetupExperiment(cs, fmi2True, 1e-6, 0.0, fmi2False, 0.0), fmi2OK);
    EXPECT(fmi2EnterInitializationMode(cs), fmi2OK);
    EXPECT(fmi2ExitInitializationMode(cs), fmi2OK);
    EXPECT(fmi2GetReal(cs, u, 1, value), fmi2OK);
    u0 = value[0];
    for (k = 0; k < 500; k++) {
        value[0] = u0 * (1.0 + 0.01 * sin(0.1 * k));
        rates[0] = 0.1 * value[0]; rates[1] = -0.2 * value[0]; rates[2] = 0.3 * value[0];
        EXPECT(fmi2SetReal(cs, u, 1, value), fmi2OK);
        EXPECT(fmi2SetRealInputDerivatives(cs, us, 3, orders, rates), fmi2OK);
        EXPECT(fmi2DoStep(cs, time, 1e-5, fmi2True), fmi2OK);
        time += 1e-5;
        EXPECT(fmi2GetReal(cs, outs, 4, value), fmi2OK);
        EXPECT(fmi2GetRealOutputDerivatives(cs, outs, 4, two, value), fmi2OK);
        if (k % 50 == 0) {
            EXPECT(fmi2GetFMUstate(cs, &s), fmi2OK);
            EXPECT(fmi2SerializedFMUstateSize(cs, s, &size), fmi2OK);
            if (size > sizeof blob) return 1;
            EXPECT(fmi2SerializeFMUstate(cs, s, blob, size), fmi2OK);
            EXPECT(fmi2DeSerializeFMUstate(cs, blob, size, &t), fmi2OK);
            EXPECT(fmi2SetFMUstate(cs, t), fmi2OK);
            EXPECT(fmi2FreeFMUstate(cs, &t), fmi2OK);
            EXPECT(fmi2FreeFMUstate(cs, &s), fmi2OK);
        }
    }
    /* refusals: their log lines are formatted */
    EXPECT(fmi2SetReal(cs, bad, 1, value), fmi2Error);
    EXPECT(fmi2SetReal(cs, u, 1, nan), fmi2Error);
    EXPECT(fmi2DoStep(cs, time + 1.0, 1e-5, fmi2True), fmi2Error);
    EXPECT(fmi2GetDerivatives(cs, dx, EMC_N_STATES), fmi2Error);
    /* Model Exchange: 1000 forward-Euler steps of 1e-11 s */
    EXPECT(fmi2SetupExperiment(me, fmi2False, 0.0, 0.0, fmi2False, 0.0), fmi2OK);
    EXPECT(fmi2EnterInitializationMode(me), fmi2OK);
    EXPECT(fmi2ExitInitializationMode(me), fmi2OK);
    EXPECT(fmi2NewDiscreteStates(me, &info), fmi2OK);
    EXPECT(fmi2EnterContinuousTimeMode(me), fmi2OK);
    EXPECT(fmi2GetContinuousStates(me, x, EMC_N_STATES), fmi2OK);
    EXPECT(fmi2GetNominalsOfContinuousStates(me, dx, EMC_N_STATES), fmi2OK);
    for (k = 0; k < 1000; k++) {
        EXPECT(fmi2SetTime(me, k * 1e-11), fmi2OK);
        EXPECT(fmi2SetContinuousStates(me, x, EMC_N_STATES), fmi2OK);
        EXPECT(fmi2GetDerivatives(me, dx, EMC_N_STATES), fmi2OK);
        EXPECT(fmi2GetEventIndicators(me, z, 1), fmi2OK);
        EXPECT(fmi2GetDirectionalDerivative(me, der, 1, q, 1, seed, value), fmi2OK);
        for (i = 0; i < EMC_N_STATES; i++) x[i] += 1e-11 * dx[i];
        EXPECT(fmi2CompletedIntegratorStep(me, fmi2True, &enter, &stop), fmi2OK);
    }
    EXPECT(fmi2SetContinuousStates(me, nan, 1), fmi2Error);
    EXPECT(fmi2Terminate(me), fmi2OK);
    EXPECT(fmi2Terminate(cs), fmi2OK);
    fmi2FreeInstance(me);
    fmi2FreeInstance(cs);
    printf("%ld allocations after instantiation\n%d mismatches\n", allocations - before, failures);
    return failures;
}
