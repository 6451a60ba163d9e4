/* emcosim's native controller FMUs: the controller model kind of the FMI 2.0 framework (emc_fmi2.h, emc_fmi2.c).
 *
 * The model (emc_controller.h) supplies the law u(inputs) of components.laws (any n_m, n_e) and its Jacobian, with
 * the feasible reference of Definition 1 and the design's checks; this file
 * supplies what the framework asks of a model: the data (parameters, gains, strict, the inputs and the input
 * rates the master set), the roles of the variables, get/set, the design's checks at
 * fmi2ExitInitializationMode, du/dt (fmi2GetRealOutputDerivatives, order 1, from the input derivatives the
 * master set: orders >= 2 are accepted and dropped, as the twin's orderUsed = 1) and the directional
 * derivatives. No continuous states. u depends on the inputs only (direct feedthrough): it is computed when
 * read; doStep only checks that it can be computed (fmi2Discard otherwise).
 *
 * A u that cannot be computed (a reference that is not feasible, Definition 1: q* outside the domain, no real
 * x_e*, Newton's method failing; a u that is not finite) is answered with fmi2Error (fmi2Discard in doStep) and one
 * log line, never with NaN. Where controller.c has them (EMC_DESIGN_CHECKED: n = 2 n_m + n_e <= 16), the
 * design's conditions (components.certificates.design_checks: the matrices of components.laws.
 * design_matrices_at_reference at the reference emc_ctrl_reference solves, from controller.c's emc_ctrl_design) are
 * checked at fmi2ExitInitializationMode as the twin checks
 * them (fmus/controller.py): a violated one is logged as a warning with strict = 0 and refuses initialization with
 * strict = 1, with the twin's words and numbers; elsewhere (n > 16) strict = 1 is refused.
 *
 * Sizes come from emc_config.h: EMC_N_CONTROLLER_INPUTS inputs and EMC_N_OUTPUTS outputs (u, n_e of them), the law's
 * Jacobian row-major (outputs x inputs); from controller.c emc_ctrl_law (u, du/d inputs, or why the reference is not
 * feasible) and emc_ctrl_check (the design's construction checks).
 */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "emc_fmi2.h"
#include "emc_controller.h"
#include "emc_design.h"

#define EMC_NI EMC_N_CONTROLLER_INPUTS
#define EMC_NO EMC_N_OUTPUTS

/* the controller's data: everything that changes after instantiation (an FMU state is a copy) */
typedef struct {
    emc_common s;
    int strict;
    double par[EMC_N_PARAMETERS];
    double gain[EMC_N_GAINS];
    double in[EMC_NI];
    double rate[EMC_NI];                   /* d in / dt the master set for this communication point */
} emc_data;

const size_t EMC_DATA_SIZE = sizeof(emc_data);
const fmi2ValueReference EMC_VARIABLE_COUNT = EMC_N_VARIABLES;

/* ---- the design ----------------------------------------------------------------------------------- */
/* the plant's parameters' and the gains' conditions */
static fmi2Status check_values(emc_instance *c, const char *function, const emc_data *d)
{
    int bad = emc_check_parameters(d->par);
    if (bad >= 0)
        return emc_fail(c, fmi2Error, "%s: parameter %s = %.17g violates %s %s (finite, 1e-100 <= |value| <= 1e100 unless 0)",
                        function, EMC_PARAMETER_NAMES[bad], d->par[bad], EMC_PARAMETER_NAMES[bad], EMC_PARAMETER_CONDITIONS[bad]);
    bad = emc_check_gains(d->gain);
    if (bad >= 0)
        return emc_fail(c, fmi2Error, "%s: parameter %s = %.17g violates %s %s (finite, 1e-100 <= |value| <= 1e100 unless 0)",
                        function, EMC_GAIN_NAMES[bad], d->gain[bad], EMC_GAIN_NAMES[bad], EMC_GAIN_CONDITIONS[bad]);
    return fmi2OK;
}

/* the conditions, the controller's construction checks (emc_ctrl_check: components.closed_loop); for
   regulation, the constant reference's feasibility */
static fmi2Status check_design(emc_instance *c, const char *function, const emc_data *d)
{
    double u[EMC_NO];
    char why[256];
    const char *reason;
    if (check_values(c, function, d) != fmi2OK) return fmi2Error;
    if (emc_ctrl_check(d->par, d->gain, why, sizeof why) != 0) return emc_fail(c, fmi2Error, "%s: %s", function, why);
    if (!EMC_TRACKING && (reason = emc_ctrl_law(d->par, d->gain, d->in, u, NULL)) != NULL)
        return emc_fail(c, fmi2Error, "%s: the set point q_d is not feasible (Definition 1: %s)", function, reason);
    return fmi2OK;
}

/* u and, if du is not NULL, du/d inputs (row-major) at the inputs: NULL, or why the reference is not feasible */
static const char *law(const emc_data *d, double *u, double *du)
{
    return emc_ctrl_law(d->par, d->gain, d->in, u, du);
}

/* u (and du/d inputs if du is not NULL) at the current inputs: fmi2OK, or `status` with one log line (never NaN) */
static fmi2Status compute_u(emc_instance *c, const char *function, fmi2Status status, emc_data *d, double *u, double *du)
{
    const char *reason;
    int i;
    for (i = 0; i < EMC_NI; i++)
        if (!isfinite(d->in[i]))
            return emc_fail(c, status, "%s: input %s = %g is not finite", function, EMC_INPUT_NAMES[i], d->in[i]);
    if (!(d->s.mode & M_INITIALIZED) && check_design(c, function, d) != fmi2OK)
        return status;
    reason = law(d, u, du);
    if (reason != NULL)
        return emc_fail(c, status, "%s at t = %.9g s: the reference is not feasible (Definition 1: %s)", function,
                        d->s.time, reason);
    for (i = 0; i < EMC_NO; i++)
        if (!isfinite(u[i]))
            return emc_fail(c, status, "%s at t = %.9g s: u = %g is not finite for these inputs", function, d->s.time, u[i]);
    return fmi2OK;
}

/* du/d(inputs) along `direction`, each output: the symbolic Jacobian (components.laws) */
static fmi2Status du_along(emc_instance *c, const char *function, emc_data *d, const double *direction, double *out)
{
    double J[EMC_NO * EMC_NI], u[EMC_NO];
    int i, k;
    if (compute_u(c, function, fmi2Error, d, u, J) != fmi2OK) return fmi2Error;
    for (k = 0; k < EMC_NO; k++) {
        out[k] = 0.0;
        for (i = 0; i < EMC_NI; i++) out[k] += J[k * EMC_NI + i] * direction[i];
        if (!isfinite(out[k]))
            return emc_fail(c, fmi2Error, "%s at t = %.9g s: the derivative of u is not finite", function, d->s.time);
    }
    return fmi2OK;
}

/* ---- the design's conditions (components.certificates.design_checks) ------------------------------- */
#if EMC_DESIGN_CHECKED                      /* controller.c has emc_ctrl_design (emc_config.h) */
/* the design's conditions at the inputs: fmi2OK when they hold or strict = 0 (a warning names the violated
   ones, as the twin's); fmi2Error with the twin's reason when strict = 1. With at_reference = 0 (a saved or
   deserialized FMU state) the conditions at the reference eta*(t) of the jet are left out: they held at
   initialization, at the jet of that time, and a state the FMU saved later must be restorable. */
static fmi2Status check_conditions(emc_instance *c, const char *function, const emc_data *d, int at_reference)
{
    double v[EMC_DESIGN_VALUES], ref[EMC_REFERENCE_SIZE], poly[EMC_DESIGN_MAX_ORDER + 1];
    char text[900];
    size_t used = 0;
    int k, i, failed = 0, reference = emc_ctrl_reference(d->par, d->gain, d->in, ref) == NULL;
    emc_ctrl_design(d->par, d->gain, ref, v);                 /* at eta_d or eta*(t): NaN where not feasible */
    for (k = 0; k < EMC_N_DESIGN_CHECKS; k++) {
        const emc_design_check *check = &EMC_DESIGN_CHECKS[k];
        double number[2], shift;
        const char *note = check->note;
        int verdict = EMC_HOLDS;
        if (check->at_reference && EMC_TRACKING && (!reference || !at_reference)) continue;  /* not applicable */
        if (check->count < 1 || check->count > 2) return emc_fail(c, fmi2Error, "%s: design check %d of %d: %d numbers "
                                                                  "(1 or 2)", function, k, EMC_N_DESIGN_CHECKS, check->count);
        for (i = 0; i < check->count; i++) {       /* every matrix inside v: the table is read at checked indices */
            const int o = check->number[i].offset, n = check->number[i].order;
            if (n < 1 || n > EMC_DESIGN_MAX_ORDER || o < 0 || o > EMC_DESIGN_VALUES - n * n)
                return emc_fail(c, fmi2Error, "%s: design check %s: a matrix of order %d at %d outside the %d values",
                                function, check->name, n, o, EMC_DESIGN_VALUES);
        }
        for (i = 0; i < check->count; i++) {
            const double *A = v + check->number[i].offset;
            int n = check->number[i].order;
            switch (check->test) {
            case EMC_TEST_SCALED:
                verdict = emc_scaled_definiteness(A, n, &number[i], &note);
                break;
            case EMC_TEST_HURWITZ:
                if (!emc_hurwitz_beyond_rounding(A, n, &shift)) verdict = EMC_FAILS;
                emc_characteristic_polynomial(A, n, poly);
                number[i] = emc_spectral_abscissa(poly, n);
                if (fabs(number[i]) <= shift) number[i] = 0.0;       /* on the imaginary axis within rounding */
                break;
            default:
                number[i] = emc_min_eig(A, n);
                if (check->test == EMC_TEST_POSITIVE ? !(number[i] > 0.0) : !(number[i] >= 0.0)) verdict = EMC_FAILS;
            }
        }
        if (verdict != EMC_FAILS) continue;
        used += (size_t)snprintf(text + used, sizeof text - used, "%s%s (", failed ? "; " : "", check->name);
        for (i = 0; i < check->count && used < sizeof text; i++)
            used += (size_t)snprintf(text + used, sizeof text - used, "%s%s = %.4g", i ? ", " : "",
                                     check->number[i].label, number[i]);
        if (used < sizeof text)
            used += (size_t)snprintf(text + used, sizeof text - used, note[0] ? ") [%s]" : ")%s", note);
        if (used >= sizeof text) used = sizeof text - 1;
        failed++;
    }
    if (!failed) return fmi2OK;
    if (d->strict == 1)
        return emc_fail(c, fmi2Error, "%s: the parameters violate %s's conditions: %s (strict = 1)", function,
                        EMC_DESIGN_NAME, text);
    emc_fail(c, fmi2Warning, "the parameters violate %s's conditions: %s; running anyway (strict = 0)",
             EMC_DESIGN_NAME, text);
    return fmi2OK;
}
#else
/* no emc_ctrl_design for this controller: strict = 1 is refused (use the pythonfmu twin) */
static fmi2Status check_conditions(emc_instance *c, const char *function, const emc_data *d, int at_reference)
{
    (void)at_reference;
    if (d->strict == 1)
        return emc_fail(c, fmi2Error, "%s: strict = 1 (the design checks of components.certificates) is not provided "
                        "by this native controller; use its pythonfmu twin", function);
    return fmi2OK;
}
#endif

/* ---- variables ---------------------------------------------------------------------------------- */
emc_role emc_role_of(fmi2ValueReference vr)
{
    switch (EMC_VARIABLES[vr].kind) {
    case EMC_C_PARAMETER: case EMC_C_GAIN: return EMC_ROLE_PARAMETER;
    case EMC_C_STRICT: return EMC_ROLE_INTEGER_PARAMETER;
    case EMC_C_INPUT: return EMC_ROLE_INPUT;
    default: return EMC_ROLE_OUTPUT;
    }
}

const char *emc_name_of(fmi2ValueReference vr) { return EMC_VARIABLES[vr].name; }

void emc_reset(emc_common *s)
{
    emc_data *d = (emc_data *)s;
    memcpy(d->par, EMC_PARAMETER_START, sizeof d->par);
    memcpy(d->gain, EMC_GAIN_START, sizeof d->gain);
    memcpy(d->in, EMC_INPUT_START, sizeof d->in);
}

fmi2Status emc_get_reals(emc_instance *c, emc_common *s, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[])
{
    emc_data *d = (emc_data *)s;
    double u[EMC_NO];
    int have_u = 0;
    size_t i;
    for (i = 0; i < nvr; i++) {
        const emc_c_variable *v = &EMC_VARIABLES[vr[i]];
        switch (v->kind) {
        case EMC_C_PARAMETER: value[i] = d->par[v->index]; break;
        case EMC_C_GAIN: value[i] = d->gain[v->index]; break;
        case EMC_C_INPUT: value[i] = d->in[v->index]; break;
        case EMC_C_OUTPUT:
            if (!have_u && compute_u(c, "fmi2GetReal", fmi2Error, d, u, NULL) != fmi2OK) return fmi2Error;
            have_u = 1;
            value[i] = u[v->index];
            break;
        default: break;                        /* strict: an Integer (the framework refused it) */
        }
    }
    return fmi2OK;
}

void emc_set_real(emc_common *s, fmi2ValueReference vr, fmi2Real value)
{
    emc_data *d = (emc_data *)s;
    const emc_c_variable *v = &EMC_VARIABLES[vr];
    if (v->kind == EMC_C_PARAMETER) d->par[v->index] = value;
    else if (v->kind == EMC_C_GAIN) d->gain[v->index] = value;
    else if (v->kind == EMC_C_INPUT) { d->in[v->index] = value; d->rate[v->index] = 0.0; }
}

fmi2Integer emc_get_integer(const emc_common *s, fmi2ValueReference vr) { (void)vr; return ((const emc_data *)s)->strict; }
void emc_set_integer(emc_common *s, fmi2ValueReference vr, fmi2Integer value) { (void)vr; ((emc_data *)s)->strict = value; }

/* ---- initialization and FMU states ---------------------------------------------------------------- */
fmi2Status emc_exit_initialization(emc_instance *c, emc_common *s)
{
    emc_data *d = (emc_data *)s;
    if (d->strict != 0 && d->strict != 1)
        return emc_fail(c, fmi2Error, "fmi2ExitInitializationMode: parameter strict = %d violates strict in {0, 1}", d->strict);
    if (check_design(c, "fmi2ExitInitializationMode", d) != fmi2OK) return fmi2Error;
    return check_conditions(c, "fmi2ExitInitializationMode", d, 1);
}

fmi2Status emc_check_saved(emc_instance *c, const char *function, const emc_common *s)
{
    const emc_data *d = (const emc_data *)s;
    if (d->strict != 0 && d->strict != 1)
        return emc_fail(c, fmi2Error, "%s: not an FMU state of %s", function, EMC_MODEL_IDENTIFIER);
    if (!emc_all_finite(d->par, EMC_N_PARAMETERS) || !emc_all_finite(d->gain, EMC_N_GAINS)
        || !emc_all_finite(d->in, EMC_NI) || !emc_all_finite(d->rate, EMC_NI))
        return emc_fail(c, fmi2Error, "%s: the FMU state holds values that are not finite", function);
    if ((s->mode & M_INITIALIZED) && check_design(c, function, d) != fmi2OK) return fmi2Error;
    /* strict = 1: the state's parameters must meet the design's conditions as at initialization (issue 40) */
    if ((s->mode & M_INITIALIZED) && d->strict == 1 && check_conditions(c, function, d, 0) != fmi2OK) return fmi2Error;
    return fmi2OK;
}

/* ---- derivatives: du/d inputs from the symbolic Jacobian (components.laws) ------------------------- */
fmi2Status emc_directional_derivative(emc_instance *c, emc_common *s, const fmi2ValueReference unknown[],
                                      size_t n_unknown, const fmi2ValueReference known[], size_t n_known,
                                      const fmi2Real seed[], fmi2Real out[])
{
    emc_data *d = (emc_data *)s;
    double v[EMC_NI], du[EMC_NO];
    size_t i;
    memset(v, 0, sizeof v);
    for (i = 0; i < n_known; i++) {
        const emc_c_variable *w = &EMC_VARIABLES[known[i]];
        if (w->kind != EMC_C_INPUT)
            return emc_fail(c, fmi2Error, "fmi2GetDirectionalDerivative: %s is not a known (an input)", w->name);
        v[w->index] += seed[i];
    }
    for (i = 0; i < n_unknown; i++)
        if (EMC_VARIABLES[unknown[i]].kind != EMC_C_OUTPUT)
            return emc_fail(c, fmi2Error, "fmi2GetDirectionalDerivative: %s is not an unknown (an output)",
                            EMC_VARIABLES[unknown[i]].name);
    if (n_unknown == 0) return fmi2OK;
    if (du_along(c, "fmi2GetDirectionalDerivative", d, v, du) != fmi2OK) return fmi2Error;
    for (i = 0; i < n_unknown; i++) out[i] = du[EMC_VARIABLES[unknown[i]].index];
    return fmi2OK;
}

/* ---- Co-Simulation -------------------------------------------------------------------------------- */
fmi2Status emc_set_input_derivatives(emc_instance *c, emc_common *s, const fmi2ValueReference vr[], size_t nvr,
                                     const fmi2Integer order[], const fmi2Real value[])
{
    emc_data *d = (emc_data *)s;
    size_t i;
    (void)c;
    for (i = 0; i < nvr; i++)                 /* orders >= 2 are dropped: du/dt needs the first ones only */
        if (order[i] == 1) d->rate[EMC_VARIABLES[vr[i]].index] = value[i];
    return fmi2OK;
}

fmi2Status emc_get_output_derivatives(emc_instance *c, emc_common *s, const fmi2ValueReference vr[], size_t nvr,
                                      const fmi2Integer order[], fmi2Real value[])
{
    emc_data *d = (emc_data *)s;
    double du[EMC_NO];
    size_t i;
    for (i = 0; i < nvr; i++) {
        if (EMC_VARIABLES[vr[i]].kind != EMC_C_OUTPUT)
            return emc_fail(c, fmi2Error, "fmi2GetRealOutputDerivatives: %s is not a Real output", EMC_VARIABLES[vr[i]].name);
        if (order[i] != 1)
            return emc_fail(c, fmi2Error, "fmi2GetRealOutputDerivatives: order %d for output %s is not in 1..1",
                            (int)order[i], EMC_VARIABLES[vr[i]].name);
    }
    if (du_along(c, "fmi2GetRealOutputDerivatives", d, d->rate, du) != fmi2OK) return fmi2Error;
    for (i = 0; i < nvr; i++) value[i] = du[EMC_VARIABLES[vr[i]].index];
    return fmi2OK;
}

fmi2Status emc_do_step(emc_instance *c, emc_common *s, double h)
{
    emc_data *d = (emc_data *)s;
    double u[EMC_NO];
    (void)h;
    if (compute_u(c, "fmi2DoStep", fmi2Discard, d, u, NULL) != fmi2OK) return fmi2Discard;
    memset(d->rate, 0, sizeof d->rate);     /* set again by the master for the next step */
    return fmi2OK;
}

/* ---- Model Exchange: no continuous states, no event indicators ------------------------------------ */
EMC_WITHOUT_STATES
