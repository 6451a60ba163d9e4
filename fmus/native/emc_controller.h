/* emcosim's FMI 2.0 framework in C, controllers: what a controller model supplies (docs/native-fmus.md).
 *
 * emc_config.h (fmus/native_build.py): EMC_MODEL_IDENTIFIER, EMC_GUID, EMC_N_PARAMETERS (the plant's),
 * EMC_N_GAINS, EMC_N_CONTROLLER_INPUTS (q, p, x_e, then the jet when tracking), EMC_N_VARIABLES,
 * EMC_TRACKING, EMC_STRICT_PH (1: eq. pHcondition strictly, Proposition 1; 0: weakly, Proposition 2;
 * -1: not asked, the theorems), EMC_ASK_K_C (1: k_c > 0 is a condition);
 * controller.c (components.c_codegen.controller_c_source): the law and its Jacobian; model.c: the plant's
 * parameter conditions (emc_check_parameters).
 */
#ifndef EMC_CONTROLLER_H
#define EMC_CONTROLLER_H

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

#define EMC_CTRL_FUNCTION(name) void emc_ctrl_##name(const double *par, const double *gain, const double *in, double *out)
EMC_CTRL_FUNCTION(u);
EMC_CTRL_FUNCTION(du);
EMC_CTRL_FUNCTION(reference);
EMC_CTRL_FUNCTION(conditions);
int emc_check_gains(const double *gain);
int emc_check_parameters(const double *par);

#endif
