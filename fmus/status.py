"""FMI 2.0 status codes (fmi2Status) and interface types (fmi2Type) as the slave's `fmi2_*` methods return and
take them."""
OK, WARNING, DISCARD, ERROR = 0, 1, 2, 3
DONE = (OK, "")                      # the answer of a call that succeeded with nothing to say
MODEL_EXCHANGE, CO_SIMULATION = 0, 1  # fmi2Instantiate's fmuType
