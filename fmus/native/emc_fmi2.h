/* emcosim's FMI 2.0 framework in C: the contract between the framework (emc_fmi2.c) and a model kind
 * (emc_plant.c, emc_controller.c, emc_reference.c). docs/native-fmus.md, "The framework".
 *
 * This is the modelica Reference-FMUs' split. The framework supplies every FMI 2.0 function: the state
 * machines of FMI 2.0 sections 3.2.3 (Model Exchange) and 4.2.4 (Co-Simulation), the instance, the checks of
 * every argument before it is read (NULL pointers with a count > 0, value references, types, causalities,
 * modes, finite values, sizes), get/set by value reference, the FMU state (a fixed pool inside the instance;
 * get, set, free, serialize, deserialize, each checked) and logging. A model kind supplies its data, the
 * roles of its variables and its equations through the functions declared below; it is called only after
 * the framework has checked the instance, the mode and every argument it can check generically.
 *
 * A model's data is one struct whose first member is emc_common; it holds everything that changes after
 * fmi2Instantiate, so that an FMU state is a copy of it (EMC_DATA_SIZE bytes, no pointers).
 */
#ifndef EMC_FMI2_H
#define EMC_FMI2_H

#include <stddef.h>

#include "fmi2Functions.h"

/* the modes of the state machines (one bit each: a function's mask is the modes it may be called in) */
enum {
    M_INSTANTIATED = 1 << 0, M_INITIALIZATION = 1 << 1, M_EVENT = 1 << 2, M_CONTINUOUS = 1 << 3,
    M_TERMINATED = 1 << 4, M_STEP = 1 << 6
};
#define M_ANY (M_INSTANTIATED | M_INITIALIZATION | M_EVENT | M_CONTINUOUS | M_TERMINATED | M_STEP)
#define M_INITIALIZED (M_EVENT | M_CONTINUOUS | M_TERMINATED | M_STEP)

/* the framework's part of a model's data (the first member of the model's struct) */
typedef struct {
    unsigned magic;           /* EMC_DATA_MAGIC: a model's data (checked in a deserialized FMU state) */
    int mode;                 /* one of the modes above */
    int in_use;               /* a slot of the FMU-state pool that holds a state */
    double time;              /* the FMU's time: fmi2SetTime (ME), the end of the last step (CS) */
    double start_time;        /* fmi2SetupExperiment's */
    int tolerance_defined;
    double tolerance;         /* fmi2SetupExperiment's */
} emc_common;

typedef struct emc_instance emc_instance;

/* ---- what the framework offers a model ---------------------------------------------------------- */
/* log one line "<identifier>: <text>" with `status` (fmi2Discard: category logStatusDiscard, else logStatusError;
   logged even with logging off) and return `status` */
fmi2Status emc_fail(emc_instance *c, fmi2Status status, const char *format, ...);
fmi2Type emc_interface(const emc_instance *c);      /* fmi2ModelExchange or fmi2CoSimulation */
const char *emc_mode_name(int mode);                /* "in step mode (after initialization)", ... */
int emc_all_finite(const double *v, size_t n);

/* ---- what a model supplies ------------------------------------------------------------------------ */
/* the role of a value reference: which calls may set it, and when */
typedef enum {
    EMC_ROLE_PARAMETER,         /* a Real parameter: set before fmi2ExitInitializationMode only */
    EMC_ROLE_INPUT,             /* a Real input: set in any mode but after fmi2Terminate */
    EMC_ROLE_OUTPUT,            /* a Real that is computed (output, derivative, time): never set */
    EMC_ROLE_INTEGER_PARAMETER  /* an Integer parameter: set before fmi2ExitInitializationMode only */
} emc_role;

extern const size_t EMC_DATA_SIZE;          /* sizeof the model's data struct (emc_common first) */
extern const fmi2ValueReference EMC_VARIABLE_COUNT;   /* value references are 0 .. EMC_VARIABLE_COUNT - 1 */
extern const size_t EMC_STATE_COUNT;        /* continuous states (Model Exchange) */
extern const size_t EMC_EVENT_INDICATOR_COUNT;

emc_role emc_role_of(fmi2ValueReference vr);               /* vr < EMC_VARIABLE_COUNT */
const char *emc_name_of(fmi2ValueReference vr);            /* the variable's name (log lines) */
void emc_reset(emc_common *d);                             /* the start values (emc_common is set by the framework) */

/* get: vr checked (existing, Real); fmi2OK or fmi2Error with one log line; the framework refuses a value
   that is not finite */
fmi2Status emc_get_reals(emc_instance *c, emc_common *d, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[]);
/* set, after the framework checked every value (role, mode, finite): cannot fail */
void emc_set_real(emc_common *d, fmi2ValueReference vr, fmi2Real value);
fmi2Integer emc_get_integer(const emc_common *d, fmi2ValueReference vr);
void emc_set_integer(emc_common *d, fmi2ValueReference vr, fmi2Integer value);

/* fmi2ExitInitializationMode: the model's checks and its initial values; fmi2OK or fmi2Error */
fmi2Status emc_exit_initialization(emc_instance *c, emc_common *d);
/* a saved or deserialized FMU state (the framework checked magic, mode and times): its values valid? */
fmi2Status emc_check_saved(emc_instance *c, const char *function, const emc_common *d);

/* fmi2GetDirectionalDerivative: references checked to exist, seeds checked to be finite */
fmi2Status emc_directional_derivative(emc_instance *c, emc_common *d, const fmi2ValueReference unknown[],
                                      size_t n_unknown, const fmi2ValueReference known[], size_t n_known,
                                      const fmi2Real seed[], fmi2Real out[]);

/* Co-Simulation. Input derivatives: references checked to exist and to be inputs, values finite,
   orders >= 1 (a model refuses the orders it cannot take). Output derivatives: references checked to
   exist, order not NULL. doStep: the time and step checked; the framework advances the time on fmi2OK. */
fmi2Status emc_set_input_derivatives(emc_instance *c, emc_common *d, const fmi2ValueReference vr[], size_t nvr,
                                     const fmi2Integer order[], const fmi2Real value[]);
fmi2Status emc_get_output_derivatives(emc_instance *c, emc_common *d, const fmi2ValueReference vr[], size_t nvr,
                                      const fmi2Integer order[], fmi2Real value[]);
fmi2Status emc_do_step(emc_instance *c, emc_common *d, double h);

/* Model Exchange, called only with EMC_STATE_COUNT > 0 (or EMC_EVENT_INDICATOR_COUNT > 0) and arrays of that
   size checked not to be NULL */
void emc_get_states(const emc_common *d, double *x);
void emc_set_states(emc_common *d, const double *x);        /* x checked to be finite */
fmi2Status emc_derivatives(emc_instance *c, emc_common *d, double *dx);
fmi2Status emc_event_indicators(emc_instance *c, emc_common *d, double *z);
fmi2Status emc_nominals(emc_instance *c, emc_common *d, double *nominal);
/* fmi2NewDiscreteStates: eventInfo zeroed by the framework */
fmi2Status emc_new_discrete_states(emc_instance *c, emc_common *d, fmi2EventInfo *info);

/* the Model Exchange functions of a model without continuous states or event indicators (the framework never
   calls them: EMC_STATE_COUNT = EMC_EVENT_INDICATOR_COUNT = 0) */
#define EMC_WITHOUT_STATES                                                                                  \
    const size_t EMC_STATE_COUNT = 0;                                                                       \
    const size_t EMC_EVENT_INDICATOR_COUNT = 0;                                                             \
    fmi2Status emc_new_discrete_states(emc_instance *c, emc_common *d, fmi2EventInfo *info)                 \
    { (void)c; (void)d; (void)info; return fmi2OK; }                                                        \
    void emc_get_states(const emc_common *d, double *x) { (void)d; (void)x; }                               \
    void emc_set_states(emc_common *d, const double *x) { (void)d; (void)x; }                               \
    fmi2Status emc_derivatives(emc_instance *c, emc_common *d, double *dx)                                  \
    { (void)c; (void)d; (void)dx; return fmi2OK; }                                                          \
    fmi2Status emc_event_indicators(emc_instance *c, emc_common *d, double *z)                              \
    { (void)c; (void)d; (void)z; return fmi2OK; }                                                           \
    fmi2Status emc_nominals(emc_instance *c, emc_common *d, double *nominal)                                \
    { (void)c; (void)d; (void)nominal; return fmi2OK; }

#endif
