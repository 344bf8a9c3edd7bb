/* The door as an FMI 3.0 FMU: every function of the standard's API, model exchange and
 * co-simulation in one binary (no scheduled execution, no clocks, no event mode in
 * co-simulation). The work is done by door_model.c; this file turns the FMI 3 calls into
 * its calls and its statuses into fmi3Status. */
#include <string.h>

#include "door_model.h"
#include "fmi3Functions.h"

typedef struct {
    DoorInstance door; /* first, so that a DoorInstance* is a Fmi3Door* */
    fmi3InstanceEnvironment environment;
    fmi3LogMessageCallback log_message;
    fmi3Boolean debug_logging;
} Fmi3Door;

#define DOOR(instance) ((DoorInstance *)(instance))
#define STATUS(expr) ((expr) == DOOR_OK ? fmi3OK : fmi3Error)
/* An FMI function the door does not offer: logged, fmi3Error. */
#define NOT_OFFERED(instance, what) \
    (door_error(DOOR(instance), "%s is not offered by this FMU", what), fmi3Error)

static void log_error(const DoorInstance *door, const char *message) {
    const Fmi3Door *c = (const Fmi3Door *)door;
    if (c->log_message) c->log_message(c->environment, fmi3Error, "logStatusError", message);
}

static fmi3Instance instantiate(fmi3String instanceName, fmi3String token, int co_simulation,
                                fmi3Boolean loggingOn, fmi3InstanceEnvironment environment,
                                fmi3LogMessageCallback logMessage) {
    char why[DOOR_WHY_SIZE];
    Fmi3Door *c = (Fmi3Door *)door_new(sizeof(Fmi3Door), instanceName, token, co_simulation,
                                       log_error, why);
    if (!c) {
        if (logMessage) logMessage(environment, fmi3Error, "logStatusError", why);
        return NULL;
    }
    c->environment = environment;
    c->log_message = logMessage;
    c->debug_logging = loggingOn;
    return c;
}

const char *fmi3GetVersion(void) { return fmi3Version; }

fmi3Status fmi3SetDebugLogging(fmi3Instance instance, fmi3Boolean loggingOn, size_t nCategories,
                               const fmi3String categories[]) {
    if (!instance) return fmi3Error;
    for (size_t i = 0; i < nCategories; i++)
        if (!categories || !categories[i] || strcmp(categories[i], "logStatusError") != 0)
            return NOT_OFFERED(instance, "a log category other than logStatusError");
    ((Fmi3Door *)instance)->debug_logging = loggingOn;
    return fmi3OK;
}

fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName, fmi3String instantiationToken,
                                          fmi3String resourcePath, fmi3Boolean visible,
                                          fmi3Boolean loggingOn,
                                          fmi3InstanceEnvironment instanceEnvironment,
                                          fmi3LogMessageCallback logMessage) {
    (void)resourcePath, (void)visible;
    return instantiate(instanceName, instantiationToken, 0, loggingOn, instanceEnvironment,
                       logMessage);
}

fmi3Instance fmi3InstantiateCoSimulation(
    fmi3String instanceName, fmi3String instantiationToken, fmi3String resourcePath,
    fmi3Boolean visible, fmi3Boolean loggingOn, fmi3Boolean eventModeUsed,
    fmi3Boolean earlyReturnAllowed, const fmi3ValueReference requiredIntermediateVariables[],
    size_t nRequiredIntermediateVariables, fmi3InstanceEnvironment instanceEnvironment,
    fmi3LogMessageCallback logMessage, fmi3IntermediateUpdateCallback intermediateUpdate) {
    (void)resourcePath, (void)visible, (void)earlyReturnAllowed;
    (void)requiredIntermediateVariables, (void)intermediateUpdate;
    if (eventModeUsed || nRequiredIntermediateVariables > 0) {
        if (logMessage)
            logMessage(instanceEnvironment, fmi3Error, "logStatusError",
                       "this FMU has no event mode in co-simulation and no intermediate update");
        return NULL;
    }
    return instantiate(instanceName, instantiationToken, 1, loggingOn, instanceEnvironment,
                       logMessage);
}

fmi3Instance fmi3InstantiateScheduledExecution(
    fmi3String instanceName, fmi3String instantiationToken, fmi3String resourcePath,
    fmi3Boolean visible, fmi3Boolean loggingOn, fmi3InstanceEnvironment instanceEnvironment,
    fmi3LogMessageCallback logMessage, fmi3ClockUpdateCallback clockUpdate,
    fmi3LockPreemptionCallback lockPreemption, fmi3UnlockPreemptionCallback unlockPreemption) {
    (void)instanceName, (void)instantiationToken, (void)resourcePath, (void)visible;
    (void)loggingOn, (void)clockUpdate, (void)lockPreemption, (void)unlockPreemption;
    if (logMessage)
        logMessage(instanceEnvironment, fmi3Error, "logStatusError",
                   "this FMU does not offer scheduled execution");
    return NULL;
}

void fmi3FreeInstance(fmi3Instance instance) { door_free(DOOR(instance)); }

fmi3Status fmi3EnterInitializationMode(fmi3Instance instance, fmi3Boolean toleranceDefined,
                                       fmi3Float64 tolerance, fmi3Float64 startTime,
                                       fmi3Boolean stopTimeDefined, fmi3Float64 stopTime) {
    (void)toleranceDefined, (void)tolerance, (void)stopTimeDefined, (void)stopTime;
    return STATUS(door_enter_initialization(DOOR(instance), startTime));
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance instance) {
    return STATUS(door_exit_initialization(DOOR(instance)));
}

fmi3Status fmi3EnterEventMode(fmi3Instance instance) {
    if (door_require(DOOR(instance), MODE_EVENT | MODE_CONTINUOUS, "fmi3EnterEventMode"))
        return fmi3Error;
    DOOR(instance)->s.mode = MODE_EVENT;
    return fmi3OK;
}

fmi3Status fmi3Terminate(fmi3Instance instance) {
    if (door_require(DOOR(instance), MODE_ANY & ~MODE_INSTANTIATED, "fmi3Terminate"))
        return fmi3Error;
    DOOR(instance)->s.mode = MODE_TERMINATED;
    return fmi3OK;
}

fmi3Status fmi3Reset(fmi3Instance instance) {
    if (!instance) return fmi3Error;
    door_reset(DOOR(instance));
    return fmi3OK;
}

fmi3Status fmi3GetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                          size_t nValueReferences, fmi3Float64 values[], size_t nValues) {
    if (!instance) return fmi3Error;
    if (nValues != nValueReferences)
        return NOT_OFFERED(instance, "an array variable (nValues != nValueReferences)");
    return STATUS(door_get(DOOR(instance), valueReferences, nValueReferences, values));
}

fmi3Status fmi3SetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                          size_t nValueReferences, const fmi3Float64 values[], size_t nValues) {
    if (!instance) return fmi3Error;
    if (nValues != nValueReferences)
        return NOT_OFFERED(instance, "an array variable (nValues != nValueReferences)");
    return STATUS(door_set(DOOR(instance), valueReferences, nValueReferences, values));
}

/* The door has Float64 variables only: a value reference of any other type is unknown. */
#define NO_SUCH_TYPE(function, type, constness)                                           \
    fmi3Status function(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,  \
                        constness type values[], size_t nValues) {                         \
        (void)vr, (void)values, (void)nValues;                                             \
        return nvr == 0 ? fmi3OK : NOT_OFFERED(instance, #function " of a value reference"); \
    }
NO_SUCH_TYPE(fmi3GetFloat32, fmi3Float32, )
NO_SUCH_TYPE(fmi3GetInt8, fmi3Int8, )
NO_SUCH_TYPE(fmi3GetUInt8, fmi3UInt8, )
NO_SUCH_TYPE(fmi3GetInt16, fmi3Int16, )
NO_SUCH_TYPE(fmi3GetUInt16, fmi3UInt16, )
NO_SUCH_TYPE(fmi3GetInt32, fmi3Int32, )
NO_SUCH_TYPE(fmi3GetUInt32, fmi3UInt32, )
NO_SUCH_TYPE(fmi3GetInt64, fmi3Int64, )
NO_SUCH_TYPE(fmi3GetUInt64, fmi3UInt64, )
NO_SUCH_TYPE(fmi3GetBoolean, fmi3Boolean, )
NO_SUCH_TYPE(fmi3GetString, fmi3String, )
NO_SUCH_TYPE(fmi3SetFloat32, fmi3Float32, const)
NO_SUCH_TYPE(fmi3SetInt8, fmi3Int8, const)
NO_SUCH_TYPE(fmi3SetUInt8, fmi3UInt8, const)
NO_SUCH_TYPE(fmi3SetInt16, fmi3Int16, const)
NO_SUCH_TYPE(fmi3SetUInt16, fmi3UInt16, const)
NO_SUCH_TYPE(fmi3SetInt32, fmi3Int32, const)
NO_SUCH_TYPE(fmi3SetUInt32, fmi3UInt32, const)
NO_SUCH_TYPE(fmi3SetInt64, fmi3Int64, const)
NO_SUCH_TYPE(fmi3SetUInt64, fmi3UInt64, const)
NO_SUCH_TYPE(fmi3SetBoolean, fmi3Boolean, const)
NO_SUCH_TYPE(fmi3SetString, fmi3String, const)

fmi3Status fmi3GetBinary(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                         size_t nValueReferences, size_t valueSizes[], fmi3Binary values[],
                         size_t nValues) {
    (void)valueReferences, (void)valueSizes, (void)values, (void)nValues;
    return nValueReferences == 0 ? fmi3OK : NOT_OFFERED(instance, "fmi3GetBinary");
}

fmi3Status fmi3SetBinary(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                         size_t nValueReferences, const size_t valueSizes[],
                         const fmi3Binary values[], size_t nValues) {
    (void)valueReferences, (void)valueSizes, (void)values, (void)nValues;
    return nValueReferences == 0 ? fmi3OK : NOT_OFFERED(instance, "fmi3SetBinary");
}

fmi3Status fmi3GetClock(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                        size_t nValueReferences, fmi3Clock values[]) {
    (void)valueReferences, (void)values;
    return nValueReferences == 0 ? fmi3OK : NOT_OFFERED(instance, "fmi3GetClock");
}

fmi3Status fmi3SetClock(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                        size_t nValueReferences, const fmi3Clock values[]) {
    (void)valueReferences, (void)values;
    return nValueReferences == 0 ? fmi3OK : NOT_OFFERED(instance, "fmi3SetClock");
}

fmi3Status fmi3GetNumberOfVariableDependencies(fmi3Instance instance,
                                               fmi3ValueReference valueReference,
                                               size_t *nDependencies) {
    (void)valueReference, (void)nDependencies;
    return NOT_OFFERED(instance, "fmi3GetNumberOfVariableDependencies");
}

fmi3Status fmi3GetVariableDependencies(fmi3Instance instance, fmi3ValueReference dependent,
                                       size_t elementIndicesOfDependent[],
                                       fmi3ValueReference independents[],
                                       size_t elementIndicesOfIndependents[],
                                       fmi3DependencyKind dependencyKinds[],
                                       size_t nDependencies) {
    (void)dependent, (void)elementIndicesOfDependent, (void)independents;
    (void)elementIndicesOfIndependents, (void)dependencyKinds, (void)nDependencies;
    return NOT_OFFERED(instance, "fmi3GetVariableDependencies");
}

fmi3Status fmi3GetFMUState(fmi3Instance instance, fmi3FMUState *FMUState) {
    return STATUS(door_state_get(DOOR(instance), FMUState));
}

fmi3Status fmi3SetFMUState(fmi3Instance instance, fmi3FMUState FMUState) {
    return STATUS(door_state_set(DOOR(instance), FMUState));
}

fmi3Status fmi3FreeFMUState(fmi3Instance instance, fmi3FMUState *FMUState) {
    return STATUS(door_state_free(DOOR(instance), FMUState));
}

fmi3Status fmi3SerializedFMUStateSize(fmi3Instance instance, fmi3FMUState FMUState, size_t *size) {
    (void)instance, (void)FMUState;
    if (!size) return fmi3Error;
    *size = door_state_size();
    return fmi3OK;
}

fmi3Status fmi3SerializeFMUState(fmi3Instance instance, fmi3FMUState FMUState,
                                 fmi3Byte serializedState[], size_t size) {
    return STATUS(door_state_serialize(DOOR(instance), FMUState, (char *)serializedState, size));
}

fmi3Status fmi3DeserializeFMUState(fmi3Instance instance, const fmi3Byte serializedState[],
                                   size_t size, fmi3FMUState *FMUState) {
    return STATUS(
        door_state_deserialize(DOOR(instance), (const char *)serializedState, size, FMUState));
}

/* Directional and adjoint derivatives, configuration mode, clocks' intervals and shifts:
 * none of them is offered (providesDirectionalDerivative and the like are false). */
#define NOT_OFFERED_FUNCTION(function, ...)                   \
    fmi3Status function(fmi3Instance instance, __VA_ARGS__) { \
        return NOT_OFFERED(instance, #function);              \
    }
#if defined(__GNUC__)
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wunused-parameter"
#endif
NOT_OFFERED_FUNCTION(fmi3GetDirectionalDerivative, const fmi3ValueReference unknowns[],
                     size_t nUnknowns, const fmi3ValueReference knowns[], size_t nKnowns,
                     const fmi3Float64 seed[], size_t nSeed, fmi3Float64 sensitivity[],
                     size_t nSensitivity)
NOT_OFFERED_FUNCTION(fmi3GetAdjointDerivative, const fmi3ValueReference unknowns[],
                     size_t nUnknowns, const fmi3ValueReference knowns[], size_t nKnowns,
                     const fmi3Float64 seed[], size_t nSeed, fmi3Float64 sensitivity[],
                     size_t nSensitivity)
NOT_OFFERED_FUNCTION(fmi3GetIntervalDecimal, const fmi3ValueReference valueReferences[],
                     size_t nValueReferences, fmi3Float64 intervals[],
                     fmi3IntervalQualifier qualifiers[])
NOT_OFFERED_FUNCTION(fmi3GetIntervalFraction, const fmi3ValueReference valueReferences[],
                     size_t nValueReferences, fmi3UInt64 counters[], fmi3UInt64 resolutions[],
                     fmi3IntervalQualifier qualifiers[])
NOT_OFFERED_FUNCTION(fmi3GetShiftDecimal, const fmi3ValueReference valueReferences[],
                     size_t nValueReferences, fmi3Float64 shifts[])
NOT_OFFERED_FUNCTION(fmi3GetShiftFraction, const fmi3ValueReference valueReferences[],
                     size_t nValueReferences, fmi3UInt64 counters[], fmi3UInt64 resolutions[])
NOT_OFFERED_FUNCTION(fmi3SetIntervalDecimal, const fmi3ValueReference valueReferences[],
                     size_t nValueReferences, const fmi3Float64 intervals[])
NOT_OFFERED_FUNCTION(fmi3SetIntervalFraction, const fmi3ValueReference valueReferences[],
                     size_t nValueReferences, const fmi3UInt64 counters[],
                     const fmi3UInt64 resolutions[])
NOT_OFFERED_FUNCTION(fmi3SetShiftDecimal, const fmi3ValueReference valueReferences[],
                     size_t nValueReferences, const fmi3Float64 shifts[])
NOT_OFFERED_FUNCTION(fmi3SetShiftFraction, const fmi3ValueReference valueReferences[],
                     size_t nValueReferences, const fmi3UInt64 counters[],
                     const fmi3UInt64 resolutions[])
NOT_OFFERED_FUNCTION(fmi3ActivateModelPartition, fmi3ValueReference clockReference,
                     fmi3Float64 activationTime)
NOT_OFFERED_FUNCTION(fmi3GetOutputDerivatives, const fmi3ValueReference valueReferences[],
                     size_t nValueReferences, const fmi3Int32 orders[], fmi3Float64 values[],
                     size_t nValues)
#if defined(__GNUC__)
#pragma GCC diagnostic pop
#endif

fmi3Status fmi3EnterConfigurationMode(fmi3Instance instance) {
    return NOT_OFFERED(instance, "fmi3EnterConfigurationMode (no structural parameters)");
}

fmi3Status fmi3ExitConfigurationMode(fmi3Instance instance) {
    return NOT_OFFERED(instance, "fmi3ExitConfigurationMode (no structural parameters)");
}

fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance instance) {
    return instance ? fmi3OK : fmi3Error; /* no discrete states */
}

fmi3Status fmi3UpdateDiscreteStates(fmi3Instance instance, fmi3Boolean *discreteStatesNeedUpdate,
                                    fmi3Boolean *terminateSimulation,
                                    fmi3Boolean *nominalsOfContinuousStatesChanged,
                                    fmi3Boolean *valuesOfContinuousStatesChanged,
                                    fmi3Boolean *nextEventTimeDefined,
                                    fmi3Float64 *nextEventTime) {
    if (door_require(DOOR(instance), MODE_EVENT, "fmi3UpdateDiscreteStates")) return fmi3Error;
    fmi3Boolean *flags[] = {discreteStatesNeedUpdate, terminateSimulation,
                            nominalsOfContinuousStatesChanged, valuesOfContinuousStatesChanged,
                            nextEventTimeDefined};
    for (size_t i = 0; i < sizeof flags / sizeof flags[0]; i++)
        if (flags[i]) *flags[i] = false;
    if (nextEventTime) *nextEventTime = 0.0;
    return fmi3OK;
}

/* Model exchange */

fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance instance) {
    if (door_require(DOOR(instance), MODE_EVENT, "fmi3EnterContinuousTimeMode")) return fmi3Error;
    DOOR(instance)->s.mode = MODE_CONTINUOUS;
    return fmi3OK;
}

fmi3Status fmi3CompletedIntegratorStep(fmi3Instance instance,
                                       fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi3Boolean *enterEventMode,
                                       fmi3Boolean *terminateSimulation) {
    (void)noSetFMUStatePriorToCurrentPoint;
    if (door_require(DOOR(instance), MODE_CONTINUOUS, "fmi3CompletedIntegratorStep"))
        return fmi3Error;
    if (enterEventMode) *enterEventMode = false;
    if (terminateSimulation) *terminateSimulation = false;
    return fmi3OK;
}

fmi3Status fmi3SetTime(fmi3Instance instance, fmi3Float64 time) {
    return STATUS(door_set_time(DOOR(instance), time));
}

fmi3Status fmi3SetContinuousStates(fmi3Instance instance, const fmi3Float64 continuousStates[],
                                   size_t nContinuousStates) {
    return STATUS(door_set_states(DOOR(instance), continuousStates, nContinuousStates));
}

fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance instance, fmi3Float64 derivatives[],
                                             size_t nContinuousStates) {
    return STATUS(door_get_derivatives(DOOR(instance), derivatives, nContinuousStates));
}

fmi3Status fmi3GetEventIndicators(fmi3Instance instance, fmi3Float64 eventIndicators[],
                                  size_t nEventIndicators) {
    (void)eventIndicators;
    return STATUS(door_check_event_indicators(DOOR(instance), nEventIndicators));
}

fmi3Status fmi3GetContinuousStates(fmi3Instance instance, fmi3Float64 continuousStates[],
                                   size_t nContinuousStates) {
    return STATUS(door_get_states(DOOR(instance), continuousStates, nContinuousStates));
}

fmi3Status fmi3GetNominalsOfContinuousStates(fmi3Instance instance, fmi3Float64 nominals[],
                                             size_t nContinuousStates) {
    return STATUS(door_get_nominals(DOOR(instance), nominals, nContinuousStates));
}

static fmi3Status give_count(fmi3Instance instance, size_t *out, size_t count) {
    if (!instance || !out) return fmi3Error;
    *out = count;
    return fmi3OK;
}

fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance instance, size_t *nEventIndicators) {
    return give_count(instance, nEventIndicators, 0);
}

fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance instance, size_t *nContinuousStates) {
    return give_count(instance, nContinuousStates, DOOR_N_STATES);
}

/* Co-simulation */

fmi3Status fmi3EnterStepMode(fmi3Instance instance) {
    /* only after event mode, which this FMU's co-simulation never enters */
    if (door_require(DOOR(instance), MODE_EVENT, "fmi3EnterStepMode")) return fmi3Error;
    if (!DOOR(instance)->co_simulation) return NOT_OFFERED(instance, "step mode in model exchange");
    DOOR(instance)->s.mode = MODE_STEP;
    return fmi3OK;
}

fmi3Status fmi3DoStep(fmi3Instance instance, fmi3Float64 currentCommunicationPoint,
                      fmi3Float64 communicationStepSize, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                      fmi3Boolean *eventHandlingNeeded, fmi3Boolean *terminateSimulation,
                      fmi3Boolean *earlyReturn, fmi3Float64 *lastSuccessfulTime) {
    (void)noSetFMUStatePriorToCurrentPoint;
    DoorStatus status = door_do_step(DOOR(instance), currentCommunicationPoint,
                                     communicationStepSize);
    if (eventHandlingNeeded) *eventHandlingNeeded = false;
    if (terminateSimulation) *terminateSimulation = false;
    if (earlyReturn) *earlyReturn = false;
    if (lastSuccessfulTime && instance) *lastSuccessfulTime = DOOR(instance)->s.time;
    return STATUS(status);
}
