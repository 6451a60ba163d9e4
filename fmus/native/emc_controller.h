/* emcosim's FMI 2.0 framework in C, controllers: what a controller model supplies (docs/native-fmus.md).
 *
 * emc_config.h (fmus/native_build.py): EMC_MODEL_IDENTIFIER, EMC_GUID, EMC_N_PARAMETERS (the plant's),
 * EMC_N_GAINS, EMC_N_CONTROLLER_INPUTS (q, p, x_e, then the jet when tracking), EMC_N_OUTPUTS (u: n_e),
 * EMC_N_VARIABLES, EMC_TRACKING;
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
int emc_check_parameters(const double *par);

#endif
