/* emcosim's native Reference FMU: what its generated config supplies (fmus/native_build.py from the pythonfmu
 * twin's variables): EMC_MODEL_IDENTIFIER, EMC_GUID, EMC_N_PARAMETERS, EMC_N_VARIABLES, EMC_KIND_START and
 * EMC_P_<name>, the index of each generator parameter; the tables below. */
#ifndef EMC_REFERENCE_H
#define EMC_REFERENCE_H

#include "emc_config.h"

typedef enum { EMC_R_KIND, EMC_R_PARAMETER, EMC_R_OUTPUT, EMC_R_TIME } emc_r_kind;
typedef struct {
    emc_r_kind kind;
    int index;
    const char *name;
} emc_r_variable;

extern const emc_r_variable EMC_VARIABLES[EMC_N_VARIABLES];
extern const double EMC_PARAMETER_START[EMC_N_PARAMETERS];
extern const char *const EMC_PARAMETER_NAMES[EMC_N_PARAMETERS];
extern const char *const EMC_PARAMETER_CONDITIONS[EMC_N_PARAMETERS];
extern const int EMC_PARAMETER_KIND[EMC_N_PARAMETERS];     /* the kind whose generator uses it */

#endif
