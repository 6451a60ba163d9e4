/* A libFuzzer harness of the FMI 2.0 surface of a native FMU (issue 40; tests/test_fuzz.py builds it with the
 * sources/ of a plant, a controller or the Reference: clang -fsanitize=fuzzer,address,undefined).
 *
 * One fuzz input is one life of one instance: its first byte chooses the interface (ME or CS) and logging, the
 * rest is decoded into a sequence of FMI calls (opcode byte, then the call's arguments from the following bytes):
 * setReal / setInteger with arbitrary values (a table of hazards: subnormals, +-0, +-inf, nan, +-1e308, huge and
 * tiny, or a value near the variable's last known one, or 8 raw bytes), the initialization and its modes,
 * doStep with arbitrary times, getReal, getDirectionalDerivative with arbitrary vr lists and seeds, input and
 * output derivatives, the Model Exchange calls, FMU states (get, set, free, serialize, deserialize with mutated
 * bytes, raw bytes), reset, terminate; free at the end. No argument is illegal for the harness: the FMU must
 * check it. The oracles, besides the sanitizers (any report aborts): every status is one of FMI's five, a value
 * an fmi2OK call returns is finite, fmi2LastSuccessfulTime after an fmi2OK step is finite, and an FMU state
 * serialized by the FMU deserializes. A broken oracle calls abort() (a finding with its input saved).
 *
 * The sizes come from the FMU's own emc_config.h (EMC_GUID, EMC_N_VARIABLES) and emc_fmi2.h (EMC_STATE_COUNT,
 * EMC_EVENT_INDICATOR_COUNT), so one harness serves every kind. */
#include <math.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "emc_fmi2.h"
#include "emc_config.h"

#define MAX_OPS 96          /* calls in one input */
#define MAX_STEPS 6         /* doStep calls in one input (a step may take 1e5 RODAS4 substeps) */
#define MAX_N 48            /* value references in one call */
#define BUFFER 65536        /* a serialized FMU state */

typedef struct {
    const uint8_t *data;
    size_t size, at;
} stream;

static uint8_t byte(stream *s) { return s->at < s->size ? s->data[s->at++] : 0; }
static int done(const stream *s) { return s->at >= s->size; }

static uint32_t u32(stream *s)
{
    uint32_t v = 0;
    int i;
    for (i = 0; i < 4; i++) v = v << 8 | byte(s);
    return v;
}

static double raw_double(stream *s)
{
    uint64_t bits = 0;
    double v;
    int i;
    for (i = 0; i < 8; i++) bits = bits << 8 | byte(s);
    memcpy(&v, &bits, sizeof v);
    return v;
}

static const double HAZARDS[] = {
    0.0, -0.0, 1.0, -1.0, 0.5, 2.0, 4.0, 10.0, 1e-3, 1e-6, 1e-12, 1e-100, 1e100, -1e100,
    4.9406564584124654e-324, -4.9406564584124654e-324, 1e-310, 2.2250738585072014e-308, 1.7976931348623157e308,
    -1.7976931348623157e308, 1e308, -1.7e308, 1e300, 1e-300, 1e15, 1e-15, 3.0, 0.1,
};
#define N_HAZARDS (sizeof HAZARDS / sizeof HAZARDS[0])

static double shadow[EMC_N_VARIABLES > 0 ? EMC_N_VARIABLES : 1];   /* each Real's last known value */

/* a value for variable `vr` (or for a time / step when vr is -1) */
static double value(stream *s, long vr)
{
    uint8_t k = byte(s);
    double base = (vr >= 0 && vr < EMC_N_VARIABLES) ? shadow[vr] : 0.1;
    if (k < 64) return raw_double(s);
    if (k < 96) {
        uint8_t j = byte(s);
        if (j < 200) return HAZARDS[j % N_HAZARDS];
        return (j & 1) ? INFINITY : ((j & 2) ? -INFINITY : NAN);
    }
    if (k < 160) return base * (1.0 + ((int)byte(s) - 128) / 256.0);           /* near the last value */
    if (k < 200) return base * ldexp(1.0, (int)(byte(s) % 64) - 32);          /* its scale changed */
    if (k < 224) return base + HAZARDS[byte(s) % N_HAZARDS];
    return base;
}

static void logger(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status, fmi2String category,
                   fmi2String message, ...)
{
    (void)env; (void)name; (void)status; (void)category;
    if (message == NULL || strlen(message) > 4096) abort();     /* a message is a bounded string */
}

static const fmi2CallbackFunctions callbacks = {logger, NULL, NULL, NULL, NULL};

static void check_status(fmi2Status status)
{
    if ((int)status < (int)fmi2OK || (int)status > (int)fmi2Pending) abort();
}

static void check_finite(fmi2Status status, const double *v, size_t n)
{
    size_t i;
    check_status(status);
    if (status != fmi2OK) return;
    for (i = 0; i < n; i++)
        if (!isfinite(v[i])) {
            fprintf(stderr, "oracle: fmi2OK with a value that is not finite (%g at %zu)\n", v[i], i);
            abort();
        }
}

static size_t refs(stream *s, fmi2ValueReference *vr)
{
    size_t n = byte(s) % (MAX_N + 1), i;
    for (i = 0; i < n; i++) {
        uint8_t k = byte(s);
        vr[i] = k < 240 ? (fmi2ValueReference)(k % (EMC_N_VARIABLES + 1)) : (fmi2ValueReference)u32(s);
    }
    return n;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    stream s = {data, size, 0};
    uint8_t head = byte(&s);
    fmi2Type type = (head & 1) ? fmi2CoSimulation : fmi2ModelExchange;
    fmi2Component c;
    fmi2FMUstate states[10] = {NULL};
    static fmi2Byte buffer[BUFFER];
    fmi2ValueReference vr[MAX_N], known[MAX_N];
    fmi2Real v[MAX_N > EMC_N_VARIABLES ? MAX_N : EMC_N_VARIABLES + 1], seed[MAX_N];
    fmi2Real x[64 + 1];
    fmi2Integer iv[MAX_N];
    fmi2EventInfo info;
    fmi2Boolean flag, terminate;
    fmi2Real t;
    size_t n, m, i, len;
    int ops = 0, steps = 0;
    fmi2Status st;

    c = fmi2Instantiate("fuzz", type, EMC_GUID, NULL, &callbacks, fmi2False, (head & 2) ? fmi2True : fmi2False);
    if (c == NULL) abort();
    for (i = 0; i < (size_t)EMC_N_VARIABLES; i++) {
        fmi2ValueReference one = (fmi2ValueReference)i;
        shadow[i] = 0.0;
        if (fmi2GetReal(c, &one, 1, &shadow[i]) != fmi2OK || !isfinite(shadow[i])) shadow[i] = 0.0;
    }
    if (head & 4) {                     /* the usual start: a run that gets far (the fuzzer may skip it) */
        check_status(fmi2SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0));
        check_status(fmi2EnterInitializationMode(c));
    }
    while (!done(&s) && ops++ < MAX_OPS) {
        uint8_t op = byte(&s);
        switch (op % 32) {
        case 0: case 1: case 2:         /* fmi2SetReal */
            n = refs(&s, vr);
            for (i = 0; i < n; i++) v[i] = value(&s, (long)vr[i]);
            st = fmi2SetReal(c, vr, n, (op & 64) ? NULL : v);
            check_status(st);
            if (st == fmi2OK)
                for (i = 0; i < n; i++) if (vr[i] < EMC_N_VARIABLES) shadow[vr[i]] = v[i];
            break;
        case 3: case 4:                 /* fmi2GetReal */
            n = refs(&s, vr);
            st = fmi2GetReal(c, vr, n, v);
            check_finite(st, v, n);
            if (st == fmi2OK)
                for (i = 0; i < n; i++) if (vr[i] < EMC_N_VARIABLES) shadow[vr[i]] = v[i];
            break;
        case 5:                         /* fmi2SetInteger, fmi2GetInteger */
            n = refs(&s, vr);
            for (i = 0; i < n; i++) iv[i] = (fmi2Integer)((byte(&s) < 200) ? (int)(byte(&s) % 4) - 1 : (int)u32(&s));
            check_status((op & 64) ? fmi2GetInteger(c, vr, n, iv) : fmi2SetInteger(c, vr, n, iv));
            break;
        case 6:
            check_status(fmi2SetupExperiment(c, (fmi2Boolean)(byte(&s) & 1), value(&s, -1), value(&s, -1),
                                             (fmi2Boolean)(byte(&s) & 1), value(&s, -1)));
            break;
        case 7: check_status(fmi2EnterInitializationMode(c)); break;
        case 8: case 9: check_status(fmi2ExitInitializationMode(c)); break;
        case 10: case 11: {             /* fmi2DoStep at the FMU's time or anywhere */
            fmi2Real now = 0.0, h;
            if (steps++ >= MAX_STEPS) break;
            if (fmi2GetRealStatus(c, fmi2LastSuccessfulTime, &now) != fmi2OK) now = 0.0;
            t = (op & 64) ? value(&s, -1) : now;
            h = value(&s, -1);
            st = fmi2DoStep(c, t, h, (fmi2Boolean)(byte(&s) & 1));
            check_status(st);
            if (st == fmi2OK && type == fmi2CoSimulation) {
                fmi2Real last = 0.0;
                if (fmi2GetRealStatus(c, fmi2LastSuccessfulTime, &last) == fmi2OK && !isfinite(last)) {
                    fprintf(stderr, "oracle: fmi2DoStep(%g, %g) gave fmi2OK and the time %g\n", t, h, last);
                    abort();
                }
            }
            break;
        }
        case 12: {                      /* fmi2GetDirectionalDerivative */
            n = refs(&s, vr);
            m = refs(&s, known);
            for (i = 0; i < m; i++) seed[i] = value(&s, -1);
            st = fmi2GetDirectionalDerivative(c, vr, n, known, m, (op & 64) ? NULL : seed, v);
            check_finite(st, v, n);
            break;
        }
        case 13: {                      /* fmi2SetRealInputDerivatives */
            n = refs(&s, vr);
            for (i = 0; i < n; i++) {
                iv[i] = (fmi2Integer)((int)(byte(&s) % 20) - 1);
                v[i] = value(&s, -1);
            }
            check_status(fmi2SetRealInputDerivatives(c, vr, n, iv, v));
            break;
        }
        case 14:                        /* fmi2GetRealOutputDerivatives */
            n = refs(&s, vr);
            for (i = 0; i < n; i++) iv[i] = (fmi2Integer)((int)(byte(&s) % 5) - 1);
            st = fmi2GetRealOutputDerivatives(c, vr, n, iv, v);
            check_finite(st, v, n);
            break;
        case 15:                        /* fmi2SetTime */
            check_status(fmi2SetTime(c, value(&s, -1)));
            break;
        case 16:                        /* fmi2SetContinuousStates: near the present states or anything */
            n = EMC_STATE_COUNT < 64 ? EMC_STATE_COUNT : 64;
            if (fmi2GetContinuousStates(c, x, n) != fmi2OK) memset(x, 0, sizeof x);
            for (i = 0; i < n; i++) {
                uint8_t k = byte(&s);
                if (k < 128) x[i] *= 1.0 + ((int)byte(&s) - 128) / 1024.0;
                else if (k < 192) x[i] = value(&s, -1);
            }
            check_status(fmi2SetContinuousStates(c, x, (op & 64) ? n + 1 : n));
            break;
        case 17:                        /* the Model Exchange getters */
            n = EMC_STATE_COUNT < 64 ? EMC_STATE_COUNT : 64;
            st = fmi2GetDerivatives(c, x, n);
            check_finite(st, x, n);
            st = fmi2GetContinuousStates(c, x, n);
            check_finite(st, x, n);
            st = fmi2GetNominalsOfContinuousStates(c, x, n);
            check_finite(st, x, n);
            m = EMC_EVENT_INDICATOR_COUNT < 64 ? EMC_EVENT_INDICATOR_COUNT : 64;
            st = fmi2GetEventIndicators(c, x, m);
            check_finite(st, x, m);
            if (op & 64) check_status(fmi2GetDerivatives(c, NULL, n));
            break;
        case 18: check_status(fmi2EnterEventMode(c)); break;
        case 19: check_status(fmi2NewDiscreteStates(c, (op & 64) ? NULL : &info)); break;
        case 20: check_status(fmi2EnterContinuousTimeMode(c)); break;
        case 21:
            check_status(fmi2CompletedIntegratorStep(c, (fmi2Boolean)(byte(&s) & 1), &flag, &terminate));
            break;
        case 22:                        /* fmi2GetFMUstate, fmi2SetFMUstate, fmi2FreeFMUstate on a slot */
            i = byte(&s) % 10;
            switch (byte(&s) % 3) {
            case 0: check_status(fmi2GetFMUstate(c, &states[i])); break;
            case 1: check_status(fmi2SetFMUstate(c, states[i])); break;
            default: check_status(fmi2FreeFMUstate(c, &states[i])); break;
            }
            break;
        case 23: {                      /* serialize a state, mutate its bytes, deserialize it */
            size_t size_needed = 0, flips;
            fmi2FMUstate back = NULL;
            i = byte(&s) % 10;
            if (fmi2SerializedFMUstateSize(c, states[i], &size_needed) != fmi2OK || size_needed > BUFFER) break;
            st = fmi2SerializeFMUstate(c, states[i], buffer, size_needed);
            check_status(st);
            if (st != fmi2OK) break;
            flips = byte(&s) % 8;
            if (flips == 0) {                   /* unchanged: the FMU must take back what it wrote */
                st = fmi2DeSerializeFMUstate(c, buffer, size_needed, &back);
                if (st != fmi2OK && st != fmi2Error) abort();
                if (st == fmi2OK) check_status(fmi2FreeFMUstate(c, &back));
                break;
            }
            for (m = 0; m < flips && size_needed > 0; m++) {
                size_t at = u32(&s) % size_needed;
                uint8_t how = byte(&s);
                if (how < 128) buffer[at] ^= (fmi2Byte)byte(&s);
                else if (how < 192 && at + 8 <= size_needed) {
                    double d = value(&s, -1);
                    memcpy(buffer + at, &d, sizeof d);
                } else buffer[at] = (fmi2Byte)byte(&s);
            }
            len = (byte(&s) < 240) ? size_needed : (size_t)(u32(&s) % (BUFFER + 1));
            st = fmi2DeSerializeFMUstate(c, buffer, len, &states[i]);
            check_status(st);
            if (st == fmi2OK && (byte(&s) & 1)) {
                check_status(fmi2SetFMUstate(c, states[i]));
            }
            break;
        }
        case 24: {                      /* deserialize raw bytes from the input */
            i = byte(&s) % 10;
            len = byte(&s) * 4u;
            for (m = 0; m < len; m++) buffer[m] = (fmi2Byte)byte(&s);
            st = fmi2DeSerializeFMUstate(c, buffer, len, &states[i]);
            check_status(st);
            break;
        }
        case 25: check_status(fmi2Reset(c)); break;
        case 26: check_status(fmi2Terminate(c)); break;
        case 27: {                      /* status queries */
            fmi2Real r = 0.0;
            fmi2Boolean b = fmi2False;
            st = fmi2GetRealStatus(c, (fmi2StatusKind)(byte(&s) % 5), &r);
            check_finite(st, &r, 1);
            check_status(fmi2GetBooleanStatus(c, (fmi2StatusKind)(byte(&s) % 5), &b));
            check_status(fmi2CancelStep(c));
            break;
        }
        case 28: {                      /* logging categories */
            fmi2String categories[3] = {"logAll", "logStatusError", "nonsense"};
            check_status(fmi2SetDebugLogging(c, (fmi2Boolean)(byte(&s) & 1), byte(&s) % 4, categories));
            break;
        }
        case 29:                        /* a whole initialization at once */
            check_status(fmi2SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0));
            check_status(fmi2EnterInitializationMode(c));
            check_status(fmi2ExitInitializationMode(c));
            if (type == fmi2ModelExchange) {
                check_status(fmi2NewDiscreteStates(c, &info));
                check_status(fmi2EnterContinuousTimeMode(c));
            }
            break;
        default: {                      /* every output read (direct feedthrough, a controller's u) */
            fmi2ValueReference all[EMC_N_VARIABLES > 0 ? EMC_N_VARIABLES : 1];
            for (i = 0; i < (size_t)EMC_N_VARIABLES; i++) all[i] = (fmi2ValueReference)i;
            st = fmi2GetReal(c, all, (size_t)EMC_N_VARIABLES, v);
            check_finite(st, v, (size_t)EMC_N_VARIABLES);
            break;
        }
        }
    }
    fmi2FreeInstance(c);
    return 0;
}
