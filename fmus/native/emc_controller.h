/* emcosim's FMI 2.0 framework in C, controllers: what a controller model supplies (docs/native-fmus.md).
 *
 * emc_config.h (fmus/native_build.py): EMC_MODEL_IDENTIFIER, EMC_GUID, EMC_N_PARAMETERS (the plant's),
 * EMC_N_GAINS, EMC_N_CONTROLLER_INPUTS (q, p, x_e, then the jet when tracking), EMC_N_OUTPUTS (u: n_e),
 * EMC_N_VARIABLES, EMC_TRACKING, EMC_N_STATES (n = 2 n_m + n_e), EMC_DESIGN_CHECKED (1: controller.c has
 * emc_ctrl_design);
 * controller.c (components.c_codegen.controller_c_source): the law, its Jacobian, the feasible reference and the
 * design's checks; model.c: the plant's parameter conditions (emc_check_parameters).
 */
#ifndef EMC_CONTROLLER_H
#define EMC_CONTROLLER_H

#include <stddef.h>

#include "emc_config.h"

typedef enum {
    EMC_C_PARAMETER,   /* a parameter of the controller's model of the plant */
    EMC_C_GAIN,        /* a gain parameter of the design */
    EMC_C_STRICT,      /* the Integer parameter strict */
    EMC_C_INPUT,       /* an input: q, p, x_e, the jet */
    EMC_C_OUTPUT       /* u */
} emc_c_kind;

typedef struct {
    emc_c_kind kind;
    int index;
    const char *name;
} emc_c_variable;

extern const emc_c_variable EMC_VARIABLES[EMC_N_VARIABLES];
extern const double EMC_PARAMETER_START[EMC_N_PARAMETERS];
extern const char *const EMC_PARAMETER_NAMES[EMC_N_PARAMETERS];
extern const char *const EMC_PARAMETER_CONDITIONS[EMC_N_PARAMETERS];
extern const double EMC_GAIN_START[EMC_N_GAINS];
extern const char *const EMC_GAIN_NAMES[EMC_N_GAINS];
extern const char *const EMC_GAIN_CONDITIONS[EMC_N_GAINS];
extern const double EMC_INPUT_START[EMC_N_CONTROLLER_INPUTS];
extern const char *const EMC_INPUT_NAMES[EMC_N_CONTROLLER_INPUTS];

/* u (EMC_N_OUTPUTS) at the inputs and, if du is not NULL, du/d inputs (EMC_N_OUTPUTS x EMC_N_CONTROLLER_INPUTS,
   row-major); NULL, or why the reference is not feasible (Definition 1) */
const char *emc_ctrl_law(const double *par, const double *gain, const double *in, double *u, double *du);
/* the design's construction checks (R_e_bar > 0, the weight > 0, eq. pHcondition): 0, or 1 and why */
int emc_ctrl_check(const double *par, const double *gain, char *why, size_t size);
int emc_check_gains(const double *gain);
/* the feasible reference (q*, p*, x_e*, x_e*') of Definition 1 at the inputs (EMC_REFERENCE_SIZE = 2 n_m + 2 n_e
   values at most); NULL, or why it is not feasible (then NaN) */
#define EMC_REFERENCE_SIZE (2 * EMC_N_STATES)
const char *emc_ctrl_reference(const double *par, const double *gain, const double *in, double *ref);

/* the design's conditions (components.certificates.design_checks), checked at fmi2ExitInitializationMode: warned
   with strict = 0, refused with strict = 1 (components.c_codegen.design_checks_c_source) */
typedef enum {
    EMC_TEST_POSITIVE,      /* every number (the smallest eigenvalue of a matrix's symmetric part) > 0 */
    EMC_TEST_NONNEGATIVE,   /* every number >= 0 */
    EMC_TEST_SCALED,        /* > 0 scaled to a unit diagonal, inconclusive within rounding (certificates.definiteness) */
    EMC_TEST_HURWITZ        /* Routh-Hurwitz; the number: the largest real part of an eigenvalue */
} emc_design_test;

typedef struct {
    const char *label;      /* as components.certificates names the number */
    int offset;             /* of the matrix in emc_ctrl_design's out (row-major) */
    int order;              /* the matrix is order x order */
} emc_design_number;

typedef struct {
    const char *name;
    emc_design_test test;
    int at_reference;       /* 1: not applicable when the reference at the inputs is not feasible */
    int count;
    emc_design_number number[2];
    const char *note;       /* printed with a failed check ("" for none) */
} emc_design_check;

#define EMC_DESIGN_VALUES (6 * EMC_N_STATES * EMC_N_STATES)       /* emc_ctrl_design's out holds at most this */
void emc_ctrl_design(const double *par, const double *gain, const double *ref, double *out);  /* ref: emc_ctrl_reference's */
extern const char *const EMC_DESIGN_NAME;
extern const int EMC_N_DESIGN_CHECKS;
extern const emc_design_check EMC_DESIGN_CHECKS[];
int emc_check_parameters(const double *par);

#endif
