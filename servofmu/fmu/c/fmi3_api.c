/* FMI 3.0 Model Exchange and Co-Simulation interface of a servofmu plant.
 *
 * This file and fmi2_api.c mirror each other function for function: both are thin adapters from an FMI
 * version's types and signatures (fmi3Instance and fmi3Status here, fmi2Component and fmi2Status there; FMI 3.0's
 * getters take value counts, its event handling has other out-arguments) onto one shared core (core_common.c,
 * servo_core.c), which holds all of the logic.  Sharing the adapters themselves would need macros over the two
 * standards' headers, which would hide exactly what each function's signature must be. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "fmi3Functions.h"
#include "fmu_core.h" /* servo_core.h for a plant, sampled_core.h for a sampled component */

typedef struct {
    SvInstance core; /* first member: an fmi3Instance is an SvInstance* */
    fmi3InstanceEnvironment env;
    fmi3LogMessageCallback log_message;
} Fmi3Instance;

static void fmi3_logger(SvInstance *inst, int level, const char *category, const char *message) {
    Fmi3Instance *fi = (Fmi3Instance *)inst;
    fmi3Status status = level == SV_LOG_ERROR ? fmi3Error : level == SV_LOG_WARNING ? fmi3Warning : fmi3OK;
    if (fi->log_message) fi->log_message(fi->env, status, category, message);
}

#define CORE(instance) ((SvInstance *)(instance))
#define OK_IF_ZERO(expr) ((expr) == 0 ? fmi3OK : fmi3Error)
#define CHECK_INSTANCE(instance) \
    if (!(instance)) return fmi3Error
#define FAIL(instance, ...) \
    do { sv_logf(CORE(instance), SV_LOG_ERROR, "logStatusError", __VA_ARGS__); return fmi3Error; } while (0)

static fmi3Instance instantiate(fmi3String instanceName, fmi3String instantiationToken, fmi3Boolean loggingOn,
                                fmi3InstanceEnvironment env, fmi3LogMessageCallback logMessage, int cosim) {
    Fmi3Instance *fi;
    if (instantiationToken && strcmp(instantiationToken, SV_INSTANTIATION_TOKEN) != 0) {
        if (logMessage)
            logMessage(env, fmi3Error, "logStatusError",
                       "instantiation token does not match this FMU's (" SV_INSTANTIATION_TOKEN ")");
        return NULL;
    }
    fi = (Fmi3Instance *)calloc(1, sizeof(Fmi3Instance));
    if (!fi) return NULL;
    fi->env = env;
    fi->log_message = logMessage;
    fi->core.log = fmi3_logger;
    fi->core.logging_on = loggingOn;
    fi->core.is_cosim = cosim;
    fi->core.name = sv_strdup(instanceName ? instanceName : "");
    sv_reset(&fi->core);
    return fi;
}

const char *fmi3GetVersion(void) { return fmi3Version; }

fmi3Status fmi3SetDebugLogging(fmi3Instance instance, fmi3Boolean loggingOn, size_t nCategories,
                               const fmi3String categories[]) {
    (void)nCategories; (void)categories;
    CHECK_INSTANCE(instance);
    CORE(instance)->logging_on = loggingOn;
    return fmi3OK;
}

fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName, fmi3String instantiationToken,
                                          fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                          fmi3InstanceEnvironment instanceEnvironment,
                                          fmi3LogMessageCallback logMessage) {
    (void)resourcePath; (void)visible;
    return instantiate(instanceName, instantiationToken, loggingOn, instanceEnvironment, logMessage, 0);
}

fmi3Instance fmi3InstantiateCoSimulation(fmi3String instanceName, fmi3String instantiationToken,
                                         fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                         fmi3Boolean eventModeUsed, fmi3Boolean earlyReturnAllowed,
                                         const fmi3ValueReference requiredIntermediateVariables[],
                                         size_t nRequiredIntermediateVariables,
                                         fmi3InstanceEnvironment instanceEnvironment,
                                         fmi3LogMessageCallback logMessage,
                                         fmi3IntermediateUpdateCallback intermediateUpdate) {
    (void)resourcePath; (void)visible; (void)eventModeUsed; (void)earlyReturnAllowed;
    (void)requiredIntermediateVariables; (void)nRequiredIntermediateVariables; (void)intermediateUpdate;
    return instantiate(instanceName, instantiationToken, loggingOn, instanceEnvironment, logMessage, 1);
}

fmi3Instance fmi3InstantiateScheduledExecution(fmi3String instanceName, fmi3String instantiationToken,
                                               fmi3String resourcePath, fmi3Boolean visible,
                                               fmi3Boolean loggingOn, fmi3InstanceEnvironment instanceEnvironment,
                                               fmi3LogMessageCallback logMessage, fmi3ClockUpdateCallback clockUpdate,
                                               fmi3LockPreemptionCallback lockPreemption,
                                               fmi3UnlockPreemptionCallback unlockPreemption) {
    (void)instanceName; (void)instantiationToken; (void)resourcePath; (void)visible; (void)loggingOn;
    (void)clockUpdate; (void)lockPreemption; (void)unlockPreemption;
    if (logMessage) logMessage(instanceEnvironment, fmi3Error, "logStatusError", "Scheduled Execution is not supported");
    return NULL;
}

void fmi3FreeInstance(fmi3Instance instance) {
    if (!instance) return;
    free(CORE(instance)->name);
    free(instance);
}

fmi3Status fmi3EnterInitializationMode(fmi3Instance instance, fmi3Boolean toleranceDefined, fmi3Float64 tolerance,
                                       fmi3Float64 startTime, fmi3Boolean stopTimeDefined, fmi3Float64 stopTime) {
    (void)stopTimeDefined; (void)stopTime;
    CHECK_INSTANCE(instance);
    return OK_IF_ZERO(sv_enter_initialization(CORE(instance), toleranceDefined, tolerance, startTime));
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance instance) {
    CHECK_INSTANCE(instance);
    return OK_IF_ZERO(sv_exit_initialization(CORE(instance)));
}

fmi3Status fmi3EnterEventMode(fmi3Instance instance) {
    CHECK_INSTANCE(instance);
    CORE(instance)->s.mode = SV_EVENT;
    return fmi3OK;
}

fmi3Status fmi3Terminate(fmi3Instance instance) {
    CHECK_INSTANCE(instance);
    CORE(instance)->s.mode = SV_TERMINATED;
    return fmi3OK;
}

fmi3Status fmi3Reset(fmi3Instance instance) {
    CHECK_INSTANCE(instance);
    sv_reset(CORE(instance));
    return fmi3OK;
}

fmi3Status fmi3GetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                          size_t nValueReferences, fmi3Float64 values[], size_t nValues) {
    size_t i;
    CHECK_INSTANCE(instance);
    if (nValues != nValueReferences) FAIL(instance, "fmi3GetFloat64: all variables are scalars");
    for (i = 0; i < nValueReferences; ++i)
        if (sv_get_checked(CORE(instance), valueReferences[i], &values[i]) != 0) return fmi3Error;
    return fmi3OK;
}

fmi3Status fmi3SetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                          size_t nValueReferences, const fmi3Float64 values[], size_t nValues) {
    size_t i;
    CHECK_INSTANCE(instance);
    if (nValues != nValueReferences) FAIL(instance, "fmi3SetFloat64: all variables are scalars");
    for (i = 0; i < nValueReferences; ++i)
        if (sv_set_checked(CORE(instance), valueReferences[i], values[i]) != 0) return fmi3Error;
    return fmi3OK;
}

/* The plant has Float64 variables only: any other type is an unknown reference. */
#define NO_VARIABLES_OF_TYPE(fn, ...)                                                               \
    fmi3Status fn(fmi3Instance instance, const fmi3ValueReference valueReferences[],                \
                  size_t nValueReferences, __VA_ARGS__) {                                           \
        CHECK_INSTANCE(instance);                                                                    \
        if (nValueReferences == 0) return fmi3OK;                                                    \
        FAIL(instance, #fn ": no variable of this type (value reference %u)", valueReferences[0]); \
    }

NO_VARIABLES_OF_TYPE(fmi3GetFloat32, fmi3Float32 values[], size_t nValues)
NO_VARIABLES_OF_TYPE(fmi3GetInt8, fmi3Int8 values[], size_t nValues)
NO_VARIABLES_OF_TYPE(fmi3GetUInt8, fmi3UInt8 values[], size_t nValues)
NO_VARIABLES_OF_TYPE(fmi3GetInt16, fmi3Int16 values[], size_t nValues)
NO_VARIABLES_OF_TYPE(fmi3GetUInt16, fmi3UInt16 values[], size_t nValues)
NO_VARIABLES_OF_TYPE(fmi3GetInt32, fmi3Int32 values[], size_t nValues)
NO_VARIABLES_OF_TYPE(fmi3GetUInt32, fmi3UInt32 values[], size_t nValues)
NO_VARIABLES_OF_TYPE(fmi3GetInt64, fmi3Int64 values[], size_t nValues)
NO_VARIABLES_OF_TYPE(fmi3GetUInt64, fmi3UInt64 values[], size_t nValues)
NO_VARIABLES_OF_TYPE(fmi3GetBoolean, fmi3Boolean values[], size_t nValues)
NO_VARIABLES_OF_TYPE(fmi3GetString, fmi3String values[], size_t nValues)
NO_VARIABLES_OF_TYPE(fmi3GetBinary, size_t valueSizes[], fmi3Binary values[], size_t nValues)
NO_VARIABLES_OF_TYPE(fmi3GetClock, fmi3Clock values[])
NO_VARIABLES_OF_TYPE(fmi3SetFloat32, const fmi3Float32 values[], size_t nValues)
NO_VARIABLES_OF_TYPE(fmi3SetInt8, const fmi3Int8 values[], size_t nValues)
NO_VARIABLES_OF_TYPE(fmi3SetUInt8, const fmi3UInt8 values[], size_t nValues)
NO_VARIABLES_OF_TYPE(fmi3SetInt16, const fmi3Int16 values[], size_t nValues)
NO_VARIABLES_OF_TYPE(fmi3SetUInt16, const fmi3UInt16 values[], size_t nValues)
NO_VARIABLES_OF_TYPE(fmi3SetInt32, const fmi3Int32 values[], size_t nValues)
NO_VARIABLES_OF_TYPE(fmi3SetUInt32, const fmi3UInt32 values[], size_t nValues)
NO_VARIABLES_OF_TYPE(fmi3SetInt64, const fmi3Int64 values[], size_t nValues)
NO_VARIABLES_OF_TYPE(fmi3SetUInt64, const fmi3UInt64 values[], size_t nValues)
NO_VARIABLES_OF_TYPE(fmi3SetBoolean, const fmi3Boolean values[], size_t nValues)
NO_VARIABLES_OF_TYPE(fmi3SetString, const fmi3String values[], size_t nValues)
NO_VARIABLES_OF_TYPE(fmi3SetBinary, const size_t valueSizes[], const fmi3Binary values[], size_t nValues)
NO_VARIABLES_OF_TYPE(fmi3SetClock, const fmi3Clock values[])
NO_VARIABLES_OF_TYPE(fmi3GetIntervalDecimal, fmi3Float64 intervals[], fmi3IntervalQualifier qualifiers[])
NO_VARIABLES_OF_TYPE(fmi3GetIntervalFraction, fmi3UInt64 counters[], fmi3UInt64 resolutions[],
                     fmi3IntervalQualifier qualifiers[])
NO_VARIABLES_OF_TYPE(fmi3GetShiftDecimal, fmi3Float64 shifts[])
NO_VARIABLES_OF_TYPE(fmi3GetShiftFraction, fmi3UInt64 counters[], fmi3UInt64 resolutions[])
NO_VARIABLES_OF_TYPE(fmi3SetIntervalDecimal, const fmi3Float64 intervals[])
NO_VARIABLES_OF_TYPE(fmi3SetIntervalFraction, const fmi3UInt64 counters[], const fmi3UInt64 resolutions[])
NO_VARIABLES_OF_TYPE(fmi3SetShiftDecimal, const fmi3Float64 shifts[])
NO_VARIABLES_OF_TYPE(fmi3SetShiftFraction, const fmi3UInt64 counters[], const fmi3UInt64 resolutions[])
NO_VARIABLES_OF_TYPE(fmi3GetOutputDerivatives, const fmi3Int32 orders[], fmi3Float64 values[], size_t nValues)

fmi3Status fmi3GetNumberOfVariableDependencies(fmi3Instance instance, fmi3ValueReference valueReference,
                                               size_t *nDependencies) {
    (void)valueReference; (void)nDependencies;
    FAIL(instance, "variable dependencies are given in modelDescription.xml only");
}

fmi3Status fmi3GetVariableDependencies(fmi3Instance instance, fmi3ValueReference dependent,
                                       size_t elementIndicesOfDependent[], fmi3ValueReference independents[],
                                       size_t elementIndicesOfIndependents[], fmi3DependencyKind dependencyKinds[],
                                       size_t nDependencies) {
    (void)dependent; (void)elementIndicesOfDependent; (void)independents; (void)elementIndicesOfIndependents;
    (void)dependencyKinds; (void)nDependencies;
    FAIL(instance, "variable dependencies are given in modelDescription.xml only");
}

/* ---- FMU state ----------------------------------------------------------------- */
fmi3Status fmi3GetFMUState(fmi3Instance instance, fmi3FMUState *FMUState) {
    CHECK_INSTANCE(instance);
    return OK_IF_ZERO(sv_state_get(CORE(instance), FMUState));
}

fmi3Status fmi3SetFMUState(fmi3Instance instance, fmi3FMUState FMUState) {
    CHECK_INSTANCE(instance);
    return OK_IF_ZERO(sv_state_set(CORE(instance), FMUState));
}

fmi3Status fmi3FreeFMUState(fmi3Instance instance, fmi3FMUState *FMUState) {
    (void)instance;
    if (FMUState) { free(*FMUState); *FMUState = NULL; }
    return fmi3OK;
}

fmi3Status fmi3SerializedFMUStateSize(fmi3Instance instance, fmi3FMUState FMUState, size_t *size) {
    (void)instance; (void)FMUState;
    *size = SV_STATE_SIZE;
    return fmi3OK;
}

fmi3Status fmi3SerializeFMUState(fmi3Instance instance, fmi3FMUState FMUState, fmi3Byte serializedState[],
                                 size_t size) {
    CHECK_INSTANCE(instance);
    return OK_IF_ZERO(sv_state_serialize(CORE(instance), FMUState, serializedState, size));
}

fmi3Status fmi3DeserializeFMUState(fmi3Instance instance, const fmi3Byte serializedState[], size_t size,
                                   fmi3FMUState *FMUState) {
    CHECK_INSTANCE(instance);
    return OK_IF_ZERO(sv_state_deserialize(CORE(instance), serializedState, size, FMUState));
}

/* ---- derivatives ------------------------------------------------------------------ */
fmi3Status fmi3GetDirectionalDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[],
                                        size_t nUnknowns, const fmi3ValueReference knowns[], size_t nKnowns,
                                        const fmi3Float64 seed[], size_t nSeed, fmi3Float64 sensitivity[],
                                        size_t nSensitivity) {
    CHECK_INSTANCE(instance);
    if (nSeed != nKnowns || nSensitivity != nUnknowns) FAIL(instance, "fmi3GetDirectionalDerivative: sizes");
    return OK_IF_ZERO(sv_derivative(CORE(instance), unknowns, nUnknowns, knowns, nKnowns, seed, sensitivity, 0));
}

fmi3Status fmi3GetAdjointDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[], size_t nUnknowns,
                                    const fmi3ValueReference knowns[], size_t nKnowns, const fmi3Float64 seed[],
                                    size_t nSeed, fmi3Float64 sensitivity[], size_t nSensitivity) {
    CHECK_INSTANCE(instance);
    if (nSeed != nUnknowns || nSensitivity != nKnowns) FAIL(instance, "fmi3GetAdjointDerivative: sizes");
    return OK_IF_ZERO(sv_derivative(CORE(instance), unknowns, nUnknowns, knowns, nKnowns, seed, sensitivity, 1));
}

/* ---- modes and events (the plant has no events) -------------------------------------- */
fmi3Status fmi3EnterConfigurationMode(fmi3Instance instance) {
    FAIL(instance, "the plant has no structural parameters");
}

fmi3Status fmi3ExitConfigurationMode(fmi3Instance instance) {
    FAIL(instance, "the plant has no structural parameters");
}

fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance instance) {
    CHECK_INSTANCE(instance);
    return fmi3OK;
}

fmi3Status fmi3UpdateDiscreteStates(fmi3Instance instance, fmi3Boolean *discreteStatesNeedUpdate,
                                    fmi3Boolean *terminateSimulation,
                                    fmi3Boolean *nominalsOfContinuousStatesChanged,
                                    fmi3Boolean *valuesOfContinuousStatesChanged, fmi3Boolean *nextEventTimeDefined,
                                    fmi3Float64 *nextEventTime) {
    CHECK_INSTANCE(instance);
    *discreteStatesNeedUpdate = fmi3False;
    *terminateSimulation = fmi3False;
    *nominalsOfContinuousStatesChanged = fmi3False;
    *valuesOfContinuousStatesChanged = fmi3False;
    *nextEventTimeDefined = fmi3False;
    *nextEventTime = 0.0;
    return fmi3OK;
}

fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance instance) {
    CHECK_INSTANCE(instance);
    CORE(instance)->s.mode = SV_CONTINUOUS;
    return fmi3OK;
}

fmi3Status fmi3CompletedIntegratorStep(fmi3Instance instance, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi3Boolean *enterEventMode, fmi3Boolean *terminateSimulation) {
    (void)noSetFMUStatePriorToCurrentPoint;
    CHECK_INSTANCE(instance);
    *enterEventMode = fmi3False;
    *terminateSimulation = fmi3False;
    return fmi3OK;
}

fmi3Status fmi3SetTime(fmi3Instance instance, fmi3Float64 time) {
    CHECK_INSTANCE(instance);
    CORE(instance)->s.time = time;
    CORE(instance)->dirty = 1;
    return fmi3OK;
}

fmi3Status fmi3SetContinuousStates(fmi3Instance instance, const fmi3Float64 continuousStates[],
                                   size_t nContinuousStates) {
    CHECK_INSTANCE(instance);
    if (nContinuousStates != SV_NX) FAIL(instance, "fmi3SetContinuousStates: the plant has %d states", SV_NX);
    memcpy(CORE(instance)->s.x, continuousStates, sizeof(double) * SV_NX);
    CORE(instance)->dirty = 1;
    return fmi3OK;
}

fmi3Status fmi3GetContinuousStates(fmi3Instance instance, fmi3Float64 continuousStates[], size_t nContinuousStates) {
    CHECK_INSTANCE(instance);
    if (nContinuousStates != SV_NX) FAIL(instance, "fmi3GetContinuousStates: the plant has %d states", SV_NX);
    memcpy(continuousStates, CORE(instance)->s.x, sizeof(double) * SV_NX);
    return fmi3OK;
}

fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance instance, fmi3Float64 derivatives[],
                                             size_t nContinuousStates) {
    CHECK_INSTANCE(instance);
    if (nContinuousStates != SV_NX) FAIL(instance, "fmi3GetContinuousStateDerivatives: the plant has %d states", SV_NX);
    if (sv_check_parameters(CORE(instance)) != 0) return fmi3Error;
    sv_eval(CORE(instance));
    memcpy(derivatives, CORE(instance)->xdot, sizeof(double) * SV_NX);
    return fmi3OK;
}

fmi3Status fmi3GetEventIndicators(fmi3Instance instance, fmi3Float64 eventIndicators[], size_t nEventIndicators) {
    (void)eventIndicators;
    CHECK_INSTANCE(instance);
    if (nEventIndicators != 0) FAIL(instance, "the plant has no event indicators");
    return fmi3OK;
}

fmi3Status fmi3GetNominalsOfContinuousStates(fmi3Instance instance, fmi3Float64 nominals[],
                                             size_t nContinuousStates) {
    size_t i;
    CHECK_INSTANCE(instance);
    if (nContinuousStates != SV_NX) FAIL(instance, "fmi3GetNominalsOfContinuousStates: the plant has %d states", SV_NX);
    for (i = 0; i < nContinuousStates; ++i) nominals[i] = sv_x_nominal[i];
    return fmi3OK;
}

fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance instance, size_t *nEventIndicators) {
    CHECK_INSTANCE(instance);
    *nEventIndicators = 0;
    return fmi3OK;
}

fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance instance, size_t *nContinuousStates) {
    CHECK_INSTANCE(instance);
    *nContinuousStates = SV_NX;
    return fmi3OK;
}

/* ---- Co-Simulation ------------------------------------------------------------------- */
fmi3Status fmi3EnterStepMode(fmi3Instance instance) {
    CHECK_INSTANCE(instance);
    CORE(instance)->s.mode = SV_STEP;
    return fmi3OK;
}

fmi3Status fmi3DoStep(fmi3Instance instance, fmi3Float64 currentCommunicationPoint,
                      fmi3Float64 communicationStepSize, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                      fmi3Boolean *eventHandlingNeeded, fmi3Boolean *terminateSimulation, fmi3Boolean *earlyReturn,
                      fmi3Float64 *lastSuccessfulTime) {
    SvInstance *c = CORE(instance);
    (void)noSetFMUStatePriorToCurrentPoint;
    CHECK_INSTANCE(instance);
    *eventHandlingNeeded = fmi3False;
    *terminateSimulation = fmi3False;
    *earlyReturn = fmi3False;
    *lastSuccessfulTime = c->s.time;
    if (sv_do_step(c, currentCommunicationPoint, communicationStepSize) != 0) {
        *lastSuccessfulTime = c->s.time;
        return fmi3Error;
    }
    *lastSuccessfulTime = c->s.time;
    return fmi3OK;
}

fmi3Status fmi3ActivateModelPartition(fmi3Instance instance, fmi3ValueReference clockReference,
                                      fmi3Float64 activationTime) {
    (void)clockReference; (void)activationTime;
    FAIL(instance, "Scheduled Execution is not supported");
}
