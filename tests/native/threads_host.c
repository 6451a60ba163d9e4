/* Native FMU instances are independent across threads (tests/test_native_sanitizers.py, built with
 * ThreadSanitizer): four threads each run a Co-Simulation instance of the same plant FMU (linked with its
 * sources) with inputs of their own, at the same time; each result must equal the same run made alone in
 * the main thread, bit for bit. The exit status is the number of mismatches. */
#include <pthread.h>
#include <stdio.h>
#include <string.h>

#include "fmi2Functions.h"
#include "emc_framework.h"

#define THREADS 4
#define STEPS 300

static void logger(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status, fmi2String category,
                   fmi2String message, ...)
{
    (void)env; (void)name; (void)status; (void)category; (void)message;
}

static const fmi2CallbackFunctions callbacks = {logger, NULL, NULL, NULL, NULL};

typedef struct {
    int id;
    double out[STEPS][EMC_N_STATES];
    int failed;
} job;

static fmi2ValueReference vr_of(emc_kind kind, int index)
{
    int i;
    for (i = 0; i < EMC_N_VARIABLES; i++)
        if (EMC_VARIABLES[i].kind == kind && EMC_VARIABLES[i].index == index) return (fmi2ValueReference)i;
    return 0;
}

static void *run(void *argument)
{
    job *j = (job *)argument;
    char name[32];
    fmi2Component c;
    fmi2ValueReference u = vr_of(EMC_INPUT, 0), x[EMC_N_STATES];
    int k, i;
    for (i = 0; i < EMC_N_STATES; i++) x[i] = vr_of(EMC_STATE, i);
    snprintf(name, sizeof name, "thread%d", j->id);
    c = fmi2Instantiate(name, fmi2CoSimulation, EMC_GUID, NULL, &callbacks, fmi2False, fmi2False);
    if (c == NULL) { j->failed = 1; return NULL; }
    fmi2SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0);
    fmi2EnterInitializationMode(c);
    fmi2ExitInitializationMode(c);
    for (k = 0; k < STEPS; k++) {
        fmi2Real value = EMC_INPUT_START[0] * (1.0 + 0.01 * j->id) + 1e-3 * (1 + j->id) * (k % 5);
        fmi2SetReal(c, &u, 1, &value);
        if (fmi2DoStep(c, k * 1e-5, 1e-5, fmi2True) != fmi2OK) { j->failed = 1; break; }
        fmi2GetReal(c, x, EMC_N_STATES, j->out[k]);
    }
    fmi2FreeInstance(c);
    return NULL;
}

int main(void)
{
    static job alone[THREADS], together[THREADS];
    pthread_t threads[THREADS];
    int i, mismatches = 0;
    for (i = 0; i < THREADS; i++) {
        alone[i].id = together[i].id = i;
        run(&alone[i]);
    }
    for (i = 0; i < THREADS; i++) pthread_create(&threads[i], NULL, run, &together[i]);
    for (i = 0; i < THREADS; i++) pthread_join(threads[i], NULL);
    for (i = 0; i < THREADS; i++) {
        if (alone[i].failed || together[i].failed) mismatches++;
        if (memcmp(alone[i].out, together[i].out, sizeof alone[i].out) != 0) mismatches++;
    }
    if (memcmp(alone[0].out, alone[1].out, sizeof alone[0].out) == 0) mismatches++;   /* the inputs differ */
    fprintf(stderr, "%d mismatches\n", mismatches);
    return mismatches;
}
