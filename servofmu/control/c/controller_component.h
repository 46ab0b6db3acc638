/* component.h of the controller FMU: its state is the law's. */
#include "controller_law.h"

typedef struct {
    CtrlState law;
    long next; /* index of the next sample: it falls at start_time + next*sample_time */
} ScState;
