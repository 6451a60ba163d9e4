/* emcosim's native Reference FMU: the reference model kind of the FMI 2.0 framework (emc_fmi2.h, emc_fmi2.c):
 * the reference generators of components/references.py in C (ME and CS, no states; the outputs are functions
 * of time alone).
 *
 * kind 0 constant q* = q_d; 1 sinusoid q* = offset + amplitude sin(omega t + phase) (eq. csim for the MEMS);
 * 2 smooth_step from q_from to q_to over [t_start, t_start + duration] with s(tau) = 35 tau^4 - 84 tau^5
 * + 70 tau^6 - 20 tau^7 (derivatives of order >= 4 from the right). Outputs: the jet (q*, q*', q*'', q*''');
 * fmi2GetRealOutputDerivatives of output k0 (q*^(k0)) of order k is q*^(k0 + k), k <= 3.
 * The formulas are components.references' (Constant, Sinusoid, SmoothStep.derivatives), written again here:
 * tests/test_native_fmus.py pins them to the Python at random times and parameters. The chosen kind's
 * parameters are checked (components.parameters) at fmi2ExitInitializationMode and in a saved FMU state.
 */
#include <math.h>
#include <string.h>

#include "emc_fmi2.h"
#include "emc_reference.h"

#define EMC_MAX_ORDER 6                    /* q*''' of order 3 */

/* the Reference's data: everything that changes after instantiation (an FMU state is a copy) */
typedef struct {
    emc_common s;
    int kind;
    double par[EMC_N_PARAMETERS];
} emc_data;

const size_t EMC_DATA_SIZE = sizeof(emc_data);
const fmi2ValueReference EMC_VARIABLE_COUNT = EMC_N_VARIABLES;

/* ---- the generators ------------------------------------------------------------------------------- */
/* kind in {0, 1, 2} and the chosen generator's parameters (components.parameters.Parameter.check) */
static fmi2Status check_parameters(emc_instance *c, const char *function, const emc_data *d)
{
    int i;
    if (d->kind < 0 || d->kind > 2)
        return emc_fail(c, fmi2Error, "%s: parameter kind = %d violates kind in {0, 1, 2} (0 constant, 1 sinusoid, "
                    "2 smooth_step)", function, d->kind);
    for (i = 0; i < EMC_N_PARAMETERS; i++) {
        double x = d->par[i];
        const char *cond = EMC_PARAMETER_CONDITIONS[i];
        int ok = isfinite(x) && (x == 0.0 || (fabs(x) >= 1e-100 && fabs(x) <= 1e100));
        if (strcmp(cond, "> 0") == 0) ok = ok && x > 0.0;
        if (strcmp(cond, ">= 0") == 0) ok = ok && x >= 0.0;
        if (EMC_PARAMETER_KIND[i] == d->kind && !ok)
            return emc_fail(c, fmi2Error, "%s: parameter %s = %.17g violates %s %s (finite, 1e-100 <= |value| <= 1e100 "
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

/* ---- variables ---------------------------------------------------------------------------------- */
emc_role emc_role_of(fmi2ValueReference vr)
{
    switch (EMC_VARIABLES[vr].kind) {
    case EMC_R_KIND: return EMC_ROLE_INTEGER_PARAMETER;
    case EMC_R_PARAMETER: return EMC_ROLE_PARAMETER;
    default: return EMC_ROLE_OUTPUT;           /* the jet and the time */
    }
}

const char *emc_name_of(fmi2ValueReference vr) { return EMC_VARIABLES[vr].name; }

void emc_reset(emc_common *s)
{
    emc_data *d = (emc_data *)s;
    d->kind = EMC_KIND_START;
    memcpy(d->par, EMC_PARAMETER_START, sizeof d->par);
}

fmi2Status emc_get_reals(emc_instance *c, emc_common *s, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[])
{
    emc_data *d = (emc_data *)s;
    double jet[4];
    size_t i;
    int have = 0;
    for (i = 0; i < nvr; i++) {
        const emc_r_variable *v = &EMC_VARIABLES[vr[i]];
        switch (v->kind) {
        case EMC_R_PARAMETER: value[i] = d->par[v->index]; break;
        case EMC_R_TIME: value[i] = s->time; break;
        case EMC_R_OUTPUT:
            if (!have) {
                if (!(s->mode & M_INITIALIZED) && check_parameters(c, "fmi2GetReal", d) != fmi2OK) return fmi2Error;
                derivatives(d, s->time, 3, jet);
                have = 1;
            }
            value[i] = jet[v->index];
            break;
        default: break;                        /* kind: an Integer (the framework refused it) */
        }
    }
    return fmi2OK;
}

void emc_set_real(emc_common *s, fmi2ValueReference vr, fmi2Real value)
{
    ((emc_data *)s)->par[EMC_VARIABLES[vr].index] = value;      /* the only settable Reals: the parameters */
}

fmi2Integer emc_get_integer(const emc_common *s, fmi2ValueReference vr) { (void)vr; return ((const emc_data *)s)->kind; }
void emc_set_integer(emc_common *s, fmi2ValueReference vr, fmi2Integer value) { (void)vr; ((emc_data *)s)->kind = value; }

/* ---- initialization and FMU states ---------------------------------------------------------------- */
fmi2Status emc_exit_initialization(emc_instance *c, emc_common *s)
{
    return check_parameters(c, "fmi2ExitInitializationMode", (emc_data *)s);
}

fmi2Status emc_check_saved(emc_instance *c, const char *function, const emc_common *s)
{
    const emc_data *d = (const emc_data *)s;
    if (!emc_all_finite(d->par, EMC_N_PARAMETERS))
        return emc_fail(c, fmi2Error, "%s: the FMU state holds values that are not finite", function);
    if ((s->mode & M_INITIALIZED) && check_parameters(c, function, d) != fmi2OK) return fmi2Error;
    return fmi2OK;
}

fmi2Status emc_directional_derivative(emc_instance *c, emc_common *s, const fmi2ValueReference unknown[],
                                      size_t n_unknown, const fmi2ValueReference known[], size_t n_known,
                                      const fmi2Real seed[], fmi2Real out[])
{
    (void)s; (void)unknown; (void)n_unknown; (void)known; (void)n_known; (void)seed; (void)out;
    return emc_fail(c, fmi2Error, "fmi2GetDirectionalDerivative: not provided (providesDirectionalDerivative = false; "
                    "the outputs depend on no input)");
}

/* ---- Co-Simulation -------------------------------------------------------------------------------- */
fmi2Status emc_set_input_derivatives(emc_instance *c, emc_common *s, const fmi2ValueReference vr[], size_t nvr,
                                     const fmi2Integer order[], const fmi2Real value[])
{
    (void)s; (void)vr; (void)nvr; (void)order; (void)value;      /* never called: the Reference has no inputs */
    return emc_fail(c, fmi2Error, "fmi2SetRealInputDerivatives: the Reference has no inputs (canInterpolateInputs = false)");
}

fmi2Status emc_get_output_derivatives(emc_instance *c, emc_common *s, const fmi2ValueReference vr[], size_t nvr,
                                      const fmi2Integer order[], fmi2Real value[])
{
    emc_data *d = (emc_data *)s;
    double all[EMC_MAX_ORDER + 1];
    size_t i;
    for (i = 0; i < nvr; i++) {
        if (EMC_VARIABLES[vr[i]].kind != EMC_R_OUTPUT)
            return emc_fail(c, fmi2Error, "fmi2GetRealOutputDerivatives: %s is not a Real output", EMC_VARIABLES[vr[i]].name);
        if (order[i] < 1 || order[i] > 3)
            return emc_fail(c, fmi2Error, "fmi2GetRealOutputDerivatives: order %d for output %s is not in 1..3",
                            (int)order[i], EMC_VARIABLES[vr[i]].name);
    }
    if ((s->mode & M_INITIALIZATION) && check_parameters(c, "fmi2GetRealOutputDerivatives", d) != fmi2OK)
        return fmi2Error;
    derivatives(d, s->time, EMC_MAX_ORDER, all);
    for (i = 0; i < nvr; i++) value[i] = all[EMC_VARIABLES[vr[i]].index + order[i]];
    return fmi2OK;
}

fmi2Status emc_do_step(emc_instance *c, emc_common *s, double h)
{
    (void)c; (void)s; (void)h;                 /* the outputs are functions of the time the framework advances */
    return fmi2OK;
}

/* ---- Model Exchange: no continuous states, no event indicators ------------------------------------ */
EMC_WITHOUT_STATES
