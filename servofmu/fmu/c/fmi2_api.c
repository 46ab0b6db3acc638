/* FMI 2.0 Model Exchange and Co-Simulation interface of a servofmu plant.
 *
 * This file and fmi3_api.c mirror each other function for function: both are thin adapters from an FMI
 * version's types and signatures (fmi2Component and fmi2Status here, fmi3Instance and fmi3Status there; FMI 3.0's
 * getters take value counts, its event handling has other out-arguments) onto one shared core (core_common.c,
 * servo_core.c), which holds all of the logic.  Sharing the adapters themselves would need macros over the two
 * standards' headers, which would hide exactly what each function's signature must be. */
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "fmu_core.h" /* servo_core.h for a plant, sampled_core.h for a sampled component */

typedef struct {
    SvInstance core; /* first member: an fmi2Component is an SvInstance* */
    fmi2CallbackFunctions callbacks;
} Fmi2Instance;

/* The message goes out as the format string itself with '%' doubled, not as "%s" plus an argument:
 * importers that cannot read variadic arguments (ctypes-based ones) then still see the text. */
static void fmi2_logger(SvInstance *inst, int level, const char *category, const char *message) {
    Fmi2Instance *fi = (Fmi2Instance *)inst;
    fmi2Status status = level == SV_LOG_ERROR ? fmi2Error : level == SV_LOG_WARNING ? fmi2Warning : fmi2OK;
    char format[1024];
    size_t i, n = 0;
    for (i = 0; message[i] && n + 2 < sizeof format; ++i) {
        if (message[i] == '%') format[n++] = '%';
        format[n++] = message[i];
    }
    format[n] = '\0';
    if (fi->callbacks.logger)
        fi->callbacks.logger(fi->callbacks.componentEnvironment, inst->name, status, category, format);
}

#define CORE(c) ((SvInstance *)(c))
#define OK_IF_ZERO(expr) ((expr) == 0 ? fmi2OK : fmi2Error)
#define CHECK_INSTANCE(c) \
    if (!(c)) return fmi2Error
#define FAIL(c, ...) \
    do { sv_logf(CORE(c), SV_LOG_ERROR, "logStatusError", __VA_ARGS__); return fmi2Error; } while (0)

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[]) {
    (void)nCategories; (void)categories;
    CHECK_INSTANCE(c);
    CORE(c)->logging_on = loggingOn;
    return fmi2OK;
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation, const fmi2CallbackFunctions *functions,
                              fmi2Boolean visible, fmi2Boolean loggingOn) {
    Fmi2Instance *fi;
    (void)fmuResourceLocation; (void)visible;
    if (!functions || !functions->logger) return NULL;
    if (!fmuGUID || strcmp(fmuGUID, SV_INSTANTIATION_TOKEN) != 0) {
        functions->logger(functions->componentEnvironment, instanceName, fmi2Error, "logStatusError",
                          "GUID does not match this FMU's (" SV_INSTANTIATION_TOKEN ")");
        return NULL;
    }
    fi = (Fmi2Instance *)calloc(1, sizeof(Fmi2Instance));
    if (!fi) return NULL;
    fi->callbacks = *functions;
    fi->core.log = fmi2_logger;
    fi->core.logging_on = loggingOn;
    fi->core.is_cosim = fmuType == fmi2CoSimulation;
    fi->core.name = sv_strdup(instanceName ? instanceName : "");
    sv_reset(&fi->core);
    return fi;
}

void fmi2FreeInstance(fmi2Component c) {
    if (!c) return;
    free(CORE(c)->name);
    free(c);
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance, fmi2Real startTime,
                               fmi2Boolean stopTimeDefined, fmi2Real stopTime) {
    SvInstance *inst = CORE(c);
    (void)stopTimeDefined; (void)stopTime;
    CHECK_INSTANCE(c);
    if (inst->s.mode != SV_INSTANTIATED) FAIL(c, "fmi2SetupExperiment: only after instantiation or reset");
    if (toleranceDefined && !(tolerance > 0.0 && tolerance < 1.0)) FAIL(c, "tolerance %g is not in (0, 1)", tolerance);
    if (toleranceDefined) inst->s.rtol = inst->s.atol = tolerance;
    inst->s.time = startTime;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    CHECK_INSTANCE(c);
    return OK_IF_ZERO(sv_enter_initialization(CORE(c), 0, 0.0, CORE(c)->s.time));
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    CHECK_INSTANCE(c);
    return OK_IF_ZERO(sv_exit_initialization(CORE(c)));
}

fmi2Status fmi2Terminate(fmi2Component c) {
    CHECK_INSTANCE(c);
    CORE(c)->s.mode = SV_TERMINATED;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component c) {
    CHECK_INSTANCE(c);
    sv_reset(CORE(c));
    return fmi2OK;
}

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[]) {
    size_t i;
    CHECK_INSTANCE(c);
    for (i = 0; i < nvr; ++i)
        if (sv_get_checked(CORE(c), vr[i], &value[i]) != 0) return fmi2Error;
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[]) {
    size_t i;
    CHECK_INSTANCE(c);
    for (i = 0; i < nvr; ++i)
        if (sv_set_checked(CORE(c), vr[i], value[i]) != 0) return fmi2Error;
    return fmi2OK;
}

/* The plant has Real variables only: any other type is an unknown reference. */
#define NO_VARIABLES_OF_TYPE(fn, type)                                                         \
    fmi2Status fn(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, type value[]) {  \
        (void)value;                                                                           \
        CHECK_INSTANCE(c);                                                                      \
        if (nvr == 0) return fmi2OK;                                                            \
        FAIL(c, #fn ": no variable of this type (value reference %u)", vr[0]);                  \
    }

NO_VARIABLES_OF_TYPE(fmi2GetInteger, fmi2Integer)
NO_VARIABLES_OF_TYPE(fmi2GetBoolean, fmi2Boolean)
NO_VARIABLES_OF_TYPE(fmi2GetString, fmi2String)
NO_VARIABLES_OF_TYPE(fmi2SetInteger, const fmi2Integer)
NO_VARIABLES_OF_TYPE(fmi2SetBoolean, const fmi2Boolean)
NO_VARIABLES_OF_TYPE(fmi2SetString, const fmi2String)

/* ---- FMU state ----------------------------------------------------------------------- */
fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    CHECK_INSTANCE(c);
    return OK_IF_ZERO(sv_state_get(CORE(c), FMUstate));
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate) {
    CHECK_INSTANCE(c);
    return OK_IF_ZERO(sv_state_set(CORE(c), FMUstate));
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    (void)c;
    if (FMUstate) { free(*FMUstate); *FMUstate = NULL; }
    return fmi2OK;
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate FMUstate, size_t *size) {
    (void)c; (void)FMUstate;
    *size = SV_STATE_SIZE;
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate, fmi2Byte serializedState[], size_t size) {
    CHECK_INSTANCE(c);
    return OK_IF_ZERO(sv_state_serialize(CORE(c), FMUstate, (unsigned char *)serializedState, size));
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[], size_t size,
                                   fmi2FMUstate *FMUstate) {
    CHECK_INSTANCE(c);
    return OK_IF_ZERO(sv_state_deserialize(CORE(c), (const unsigned char *)serializedState, size, FMUstate));
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown_ref[], size_t nUnknown,
                                        const fmi2ValueReference vKnown_ref[], size_t nKnown,
                                        const fmi2Real dvKnown[], fmi2Real dvUnknown[]) {
    CHECK_INSTANCE(c);
    return OK_IF_ZERO(sv_derivative(CORE(c), vUnknown_ref, nUnknown, vKnown_ref, nKnown, dvKnown, dvUnknown, 0));
}

/* ---- Model Exchange -------------------------------------------------------------------- */
fmi2Status fmi2EnterEventMode(fmi2Component c) {
    CHECK_INSTANCE(c);
    CORE(c)->s.mode = SV_EVENT;
    return fmi2OK;
}

fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *eventInfo) {
    CHECK_INSTANCE(c);
    eventInfo->newDiscreteStatesNeeded = fmi2False;
    eventInfo->terminateSimulation = fmi2False;
    eventInfo->nominalsOfContinuousStatesChanged = fmi2False;
    eventInfo->valuesOfContinuousStatesChanged = fmi2False;
    eventInfo->nextEventTimeDefined = fmi2False;
    eventInfo->nextEventTime = 0.0;
    return fmi2OK;
}

fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c) {
    CHECK_INSTANCE(c);
    CORE(c)->s.mode = SV_CONTINUOUS;
    return fmi2OK;
}

fmi2Status fmi2CompletedIntegratorStep(fmi2Component c, fmi2Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi2Boolean *enterEventMode, fmi2Boolean *terminateSimulation) {
    (void)noSetFMUStatePriorToCurrentPoint;
    CHECK_INSTANCE(c);
    *enterEventMode = fmi2False;
    *terminateSimulation = fmi2False;
    return fmi2OK;
}

fmi2Status fmi2SetTime(fmi2Component c, fmi2Real time) {
    CHECK_INSTANCE(c);
    CORE(c)->s.time = time;
    CORE(c)->dirty = 1;
    return fmi2OK;
}

fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t nx) {
    CHECK_INSTANCE(c);
    if (nx != SV_NX) FAIL(c, "fmi2SetContinuousStates: the plant has %d states", SV_NX);
    memcpy(CORE(c)->s.x, x, sizeof(double) * SV_NX);
    CORE(c)->dirty = 1;
    return fmi2OK;
}

fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real derivatives[], size_t nx) {
    CHECK_INSTANCE(c);
    if (nx != SV_NX) FAIL(c, "fmi2GetDerivatives: the plant has %d states", SV_NX);
    if (sv_check_parameters(CORE(c)) != 0) return fmi2Error;
    sv_eval(CORE(c));
    memcpy(derivatives, CORE(c)->xdot, sizeof(double) * SV_NX);
    return fmi2OK;
}

fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real eventIndicators[], size_t ni) {
    (void)eventIndicators;
    CHECK_INSTANCE(c);
    if (ni != 0) FAIL(c, "the plant has no event indicators");
    return fmi2OK;
}

fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t nx) {
    CHECK_INSTANCE(c);
    if (nx != SV_NX) FAIL(c, "fmi2GetContinuousStates: the plant has %d states", SV_NX);
    memcpy(x, CORE(c)->s.x, sizeof(double) * SV_NX);
    return fmi2OK;
}

fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x_nominal[], size_t nx) {
    size_t i;
    CHECK_INSTANCE(c);
    if (nx != SV_NX) FAIL(c, "fmi2GetNominalsOfContinuousStates: the plant has %d states", SV_NX);
    for (i = 0; i < nx; ++i) x_nominal[i] = sv_x_nominal[i];
    return fmi2OK;
}

/* ---- Co-Simulation --------------------------------------------------------------------- */
fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    (void)vr; (void)nvr; (void)order; (void)value;
    FAIL(c, "input derivatives are not supported (canInterpolateInputs=false)");
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[]) {
    (void)vr; (void)nvr; (void)order; (void)value;
    FAIL(c, "output derivatives are not supported (maxOutputDerivativeOrder=0)");
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint, fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    (void)noSetFMUStatePriorToCurrentPoint;
    CHECK_INSTANCE(c);
    return OK_IF_ZERO(sv_do_step(CORE(c), currentCommunicationPoint, communicationStepSize));
}

fmi2Status fmi2CancelStep(fmi2Component c) {
    FAIL(c, "fmi2DoStep never runs asynchronously: nothing to cancel");
}

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value) {
    (void)s; (void)value;
    FAIL(c, "fmi2GetStatus: no asynchronous step");
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value) {
    CHECK_INSTANCE(c);
    if (s == fmi2LastSuccessfulTime) { *value = CORE(c)->s.time; return fmi2OK; }
    FAIL(c, "fmi2GetRealStatus: only fmi2LastSuccessfulTime is available");
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value) {
    (void)s; (void)value;
    FAIL(c, "fmi2GetIntegerStatus: no integer status");
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value) {
    CHECK_INSTANCE(c);
    if (s == fmi2Terminated) { *value = fmi2False; return fmi2OK; }
    FAIL(c, "fmi2GetBooleanStatus: only fmi2Terminated is available");
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value) {
    (void)s; (void)value;
    FAIL(c, "fmi2GetStringStatus: no string status");
}
