/* A C host that loads a native plant FMU's binary at run time, built for linux64 (dlopen) and for win64
 * (LoadLibrary, run under wine64) from this one source (tests/test_native_fmus.py): Model Exchange
 * derivatives at a few states, then 200 Co-Simulation steps with an input polynomial; it prints every
 * number with 17 digits, so the two platforms' outputs can be compared.
 *
 *     portable_host LIBRARY GUID
 */
#include <stdio.h>
#include <stdlib.h>

#include "fmi2Functions.h"

#ifdef _WIN32
#include <windows.h>
typedef HMODULE library_t;
static library_t open_library(const char *path) { return LoadLibraryA(path); }
static void *symbol(library_t l, const char *name) { return (void *)GetProcAddress(l, name); }
#else
#include <dlfcn.h>
typedef void *library_t;
static library_t open_library(const char *path) { return dlopen(path, RTLD_NOW | RTLD_LOCAL); }
static void *symbol(library_t l, const char *name) { return dlsym(l, name); }
#endif

static void logger(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status, fmi2String category,
                   fmi2String message, ...)
{
    (void)env; (void)name; (void)status; (void)category; (void)message;
}

#define LOAD(type, name)                                                   \
    type *name = (type *)symbol(lib, #name);                               \
    if (name == NULL) { fprintf(stderr, "no symbol %s\n", #name); return 2; }

int main(int argc, char **argv)
{
    library_t lib;
    fmi2CallbackFunctions callbacks = {logger, NULL, NULL, NULL, NULL};
    fmi2Component c;
    fmi2EventInfo info;
    fmi2Real x[3], dx[3], out[4];
    fmi2ValueReference u_vr[1] = {10}, outs[4] = {11, 12, 13, 14}, us[3] = {10, 10, 10};
    fmi2Integer orders[3] = {1, 2, 3};
    fmi2Real rates[3] = {0.1, -1.0, 10.0}, u[1];
    int i, k;
    if (argc != 3) { fprintf(stderr, "usage: portable_host LIBRARY GUID\n"); return 2; }
    lib = open_library(argv[1]);
    if (lib == NULL) { fprintf(stderr, "cannot load %s\n", argv[1]); return 2; }
    {
        LOAD(fmi2InstantiateTYPE, fmi2Instantiate)
        LOAD(fmi2SetupExperimentTYPE, fmi2SetupExperiment)
        LOAD(fmi2EnterInitializationModeTYPE, fmi2EnterInitializationMode)
        LOAD(fmi2ExitInitializationModeTYPE, fmi2ExitInitializationMode)
        LOAD(fmi2NewDiscreteStatesTYPE, fmi2NewDiscreteStates)
        LOAD(fmi2EnterContinuousTimeModeTYPE, fmi2EnterContinuousTimeMode)
        LOAD(fmi2SetContinuousStatesTYPE, fmi2SetContinuousStates)
        LOAD(fmi2GetDerivativesTYPE, fmi2GetDerivatives)
        LOAD(fmi2SetRealTYPE, fmi2SetReal)
        LOAD(fmi2GetRealTYPE, fmi2GetReal)
        LOAD(fmi2SetRealInputDerivativesTYPE, fmi2SetRealInputDerivatives)
        LOAD(fmi2DoStepTYPE, fmi2DoStep)
        LOAD(fmi2FreeInstanceTYPE, fmi2FreeInstance)
        c = fmi2Instantiate("me", fmi2ModelExchange, argv[2], "", &callbacks, fmi2False, fmi2False);
        if (c == NULL) { fprintf(stderr, "fmi2Instantiate failed\n"); return 2; }
        fmi2SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0);
        fmi2EnterInitializationMode(c);
        fmi2ExitInitializationMode(c);
        fmi2NewDiscreteStates(c, &info);
        fmi2EnterContinuousTimeMode(c);
        for (i = 0; i < 5; i++) {
            x[0] = 0.001 + 0.0007 * i; x[1] = -0.01 + 0.004 * i; x[2] = 0.9 + 0.05 * i;
            u[0] = -3.0 + 1.5 * i;
            fmi2SetReal(c, u_vr, 1, u);
            fmi2SetContinuousStates(c, x, 3);
            if (fmi2GetDerivatives(c, dx, 3) != fmi2OK) { fprintf(stderr, "fmi2GetDerivatives failed\n"); return 1; }
            printf("dx %.17g %.17g %.17g\n", dx[0], dx[1], dx[2]);
        }
        fmi2FreeInstance(c);
        c = fmi2Instantiate("cs", fmi2CoSimulation, argv[2], "", &callbacks, fmi2False, fmi2False);
        if (c == NULL) { fprintf(stderr, "fmi2Instantiate (CS) failed\n"); return 2; }
        fmi2SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0);
        fmi2EnterInitializationMode(c);
        fmi2ExitInitializationMode(c);
        for (k = 0; k < 200; k++) {
            u[0] = 0.009 * (1.0 + 0.02 * (k % 7));       /* about the maglev's equilibrium voltage */
            fmi2SetReal(c, u_vr, 1, u);
            fmi2SetRealInputDerivatives(c, us, 3, orders, rates);
            if (fmi2DoStep(c, k * 1e-3, 1e-3, fmi2True) != fmi2OK) { fprintf(stderr, "doStep %d failed\n", k); return 1; }
            fmi2GetReal(c, outs, 4, out);
            if (k % 20 == 19) printf("cs %d %.17g %.17g %.17g %.17g\n", k, out[0], out[1], out[2], out[3]);
        }
        fmi2FreeInstance(c);
    }
    return 0;
}
