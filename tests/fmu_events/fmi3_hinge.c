/* The hinge (hinge.h) as an FMI 3.0 model-exchange FMU. */
#include <stdlib.h>

#include "fmi3Functions.h"
#include "hinge.h"

typedef struct {
    Hinge h; /* first: a Hinge* is a Fmi3Hinge* */
    fmi3InstanceEnvironment environment;
    fmi3LogMessageCallback log_message;
} Fmi3Hinge;

#define H(i) ((Hinge *)(i))
#define STATUS(failed) ((failed) ? fmi3Error : fmi3OK)

static void log_to_host(const Hinge *h, const char *message) {
    const Fmi3Hinge *c = (const Fmi3Hinge *)h;
    if (c->log_message) c->log_message(c->environment, fmi3Error, "logStatusError", message);
}

const char *fmi3GetVersion(void) { return fmi3Version; }

fmi3Instance fmi3InstantiateModelExchange(fmi3String name, fmi3String token, fmi3String resources,
                                          fmi3Boolean visible, fmi3Boolean loggingOn,
                                          fmi3InstanceEnvironment environment,
                                          fmi3LogMessageCallback logMessage) {
    (void)name, (void)resources, (void)visible, (void)loggingOn;
    Fmi3Hinge *c = (Fmi3Hinge *)hinge_new(sizeof(Fmi3Hinge), token);
    if (!c) return NULL;
    c->environment = environment;
    c->log_message = logMessage;
    c->h.log = log_to_host;
    return c;
}

void fmi3FreeInstance(fmi3Instance instance) { free(instance); }

fmi3Status fmi3SetDebugLogging(fmi3Instance instance, fmi3Boolean on, size_t n,
                               const fmi3String categories[]) {
    (void)on, (void)categories;
    return STATUS(!instance || n > 0);
}

fmi3Status fmi3EnterInitializationMode(fmi3Instance instance, fmi3Boolean toleranceDefined,
                                       fmi3Float64 tolerance, fmi3Float64 startTime,
                                       fmi3Boolean stopTimeDefined, fmi3Float64 stopTime) {
    (void)toleranceDefined, (void)tolerance, (void)stopTimeDefined, (void)stopTime;
    if (hinge_move(H(instance), H_INSTANTIATED, H_INITIALIZATION, "fmi3EnterInitializationMode"))
        return fmi3Error;
    H(instance)->time = startTime;
    return fmi3OK;
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance instance) {
    return STATUS(hinge_move(H(instance), H_INITIALIZATION, H_EVENT, "fmi3ExitInitializationMode"));
}

fmi3Status fmi3EnterEventMode(fmi3Instance instance) {
    return STATUS(hinge_move(H(instance), H_EVENT | H_CONTINUOUS, H_EVENT, "fmi3EnterEventMode"));
}

fmi3Status fmi3Terminate(fmi3Instance instance) {
    return STATUS(hinge_move(H(instance), H_EVENT | H_CONTINUOUS, H_TERMINATED, "fmi3Terminate"));
}

fmi3Status fmi3Reset(fmi3Instance instance) {
    if (!instance) return fmi3Error;
    hinge_reset(H(instance));
    return fmi3OK;
}

fmi3Status fmi3GetFloat64(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                          fmi3Float64 values[], size_t nValues) {
    int failed = !instance || nValues != nvr;
    for (size_t i = 0; i < nvr && !failed; i++) failed = hinge_get_real(H(instance), vr[i], &values[i]);
    return STATUS(failed);
}

fmi3Status fmi3SetFloat64(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                          const fmi3Float64 values[], size_t nValues) {
    int failed = !instance || nValues != nvr;
    for (size_t i = 0; i < nvr && !failed; i++) failed = hinge_set_real(H(instance), vr[i], values[i]);
    return STATUS(failed);
}

fmi3Status fmi3GetBoolean(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                          fmi3Boolean values[], size_t nValues) {
    int failed = !instance || nValues != nvr;
    for (size_t i = 0; i < nvr && !failed; i++) {
        int value = 0;
        failed = hinge_get_boolean(H(instance), vr[i], &value);
        values[i] = value != 0;
    }
    return STATUS(failed);
}

/* Model exchange */

fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance instance) { return STATUS(!instance); }

fmi3Status fmi3UpdateDiscreteStates(fmi3Instance instance, fmi3Boolean *needUpdate,
                                    fmi3Boolean *terminate, fmi3Boolean *nominalsChanged,
                                    fmi3Boolean *valuesChanged, fmi3Boolean *nextTimeDefined,
                                    fmi3Float64 *nextTime) {
    if (hinge_move(H(instance), H_EVENT, 0, "fmi3UpdateDiscreteStates")) return fmi3Error;
    HingeUpdate u;
    hinge_update(H(instance), &u);
    *needUpdate = *terminate = *nominalsChanged = false;
    *valuesChanged = u.states_changed != 0;
    *nextTimeDefined = u.next_time_defined != 0;
    *nextTime = u.next_time;
    return fmi3OK;
}

fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance instance) {
    return STATUS(hinge_move(H(instance), H_EVENT, H_CONTINUOUS, "fmi3EnterContinuousTimeMode"));
}

fmi3Status fmi3CompletedIntegratorStep(fmi3Instance instance, fmi3Boolean noSetPrior,
                                       fmi3Boolean *enterEventMode, fmi3Boolean *terminate) {
    (void)noSetPrior;
    if (hinge_move(H(instance), H_CONTINUOUS, 0, "fmi3CompletedIntegratorStep")) return fmi3Error;
    *enterEventMode = *terminate = false;
    return fmi3OK;
}

fmi3Status fmi3SetTime(fmi3Instance instance, fmi3Float64 time) {
    if (!instance) return fmi3Error;
    H(instance)->time = time;
    return fmi3OK;
}

fmi3Status fmi3SetContinuousStates(fmi3Instance instance, const fmi3Float64 x[], size_t nx) {
    return STATUS(!instance || hinge_states(H(instance), HINGE_SET_STATES, (double *)x, nx));
}

fmi3Status fmi3GetContinuousStates(fmi3Instance instance, fmi3Float64 x[], size_t nx) {
    return STATUS(!instance || hinge_states(H(instance), HINGE_GET_STATES, x, nx));
}

fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance instance, fmi3Float64 dx[], size_t nx) {
    return STATUS(!instance || hinge_states(H(instance), HINGE_GET_DERIVATIVES, dx, nx));
}

fmi3Status fmi3GetEventIndicators(fmi3Instance instance, fmi3Float64 z[], size_t nz) {
    return STATUS(!instance || hinge_states(H(instance), HINGE_GET_EVENT_INDICATORS, z, nz));
}

fmi3Status fmi3GetNominalsOfContinuousStates(fmi3Instance instance, fmi3Float64 nominals[],
                                             size_t nx) {
    return STATUS(!instance || hinge_states(H(instance), HINGE_GET_NOMINALS, nominals, nx));
}

fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance instance, size_t *n) {
    if (!instance) return fmi3Error;
    *n = HINGE_N_EVENT_INDICATORS;
    return fmi3OK;
}

fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance instance, size_t *n) {
    if (!instance) return fmi3Error;
    *n = HINGE_N_STATES;
    return fmi3OK;
}

/* Everything else of the API (FMPy binds every function): this FMU has no other variable
 * types, no co-simulation or scheduled execution, no FMU states, no derivatives, no
 * clocks. Each refuses with fmi3Error (an empty get or set is fmi3OK). */
#if defined(__GNUC__)
#pragma GCC diagnostic ignored "-Wunused-parameter"
#endif
#define REFUSED(function, ...) \
    fmi3Status function(fmi3Instance instance, __VA_ARGS__) { return fmi3Error; }
#define NO_SUCH_TYPE(function, type, constness)                                           \
    fmi3Status function(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, \
                        constness type values[], size_t nValues) {                        \
        return STATUS(!instance || nvr > 0);                                              \
    }
NO_SUCH_TYPE(fmi3GetFloat32, fmi3Float32, )
NO_SUCH_TYPE(fmi3SetFloat32, fmi3Float32, const)
NO_SUCH_TYPE(fmi3GetInt8, fmi3Int8, )
NO_SUCH_TYPE(fmi3SetInt8, fmi3Int8, const)
NO_SUCH_TYPE(fmi3GetUInt8, fmi3UInt8, )
NO_SUCH_TYPE(fmi3SetUInt8, fmi3UInt8, const)
NO_SUCH_TYPE(fmi3GetInt16, fmi3Int16, )
NO_SUCH_TYPE(fmi3SetInt16, fmi3Int16, const)
NO_SUCH_TYPE(fmi3GetUInt16, fmi3UInt16, )
NO_SUCH_TYPE(fmi3SetUInt16, fmi3UInt16, const)
NO_SUCH_TYPE(fmi3GetInt32, fmi3Int32, )
NO_SUCH_TYPE(fmi3SetInt32, fmi3Int32, const)
NO_SUCH_TYPE(fmi3GetUInt32, fmi3UInt32, )
NO_SUCH_TYPE(fmi3SetUInt32, fmi3UInt32, const)
NO_SUCH_TYPE(fmi3GetInt64, fmi3Int64, )
NO_SUCH_TYPE(fmi3SetInt64, fmi3Int64, const)
NO_SUCH_TYPE(fmi3GetUInt64, fmi3UInt64, )
NO_SUCH_TYPE(fmi3SetUInt64, fmi3UInt64, const)
NO_SUCH_TYPE(fmi3SetBoolean, fmi3Boolean, const)
NO_SUCH_TYPE(fmi3GetString, fmi3String, )
NO_SUCH_TYPE(fmi3SetString, fmi3String, const)
REFUSED(fmi3GetBinary, const fmi3ValueReference vr[], size_t nvr, size_t sizes[],
        fmi3Binary values[], size_t nValues)
REFUSED(fmi3SetBinary, const fmi3ValueReference vr[], size_t nvr, const size_t sizes[],
        const fmi3Binary values[], size_t nValues)
REFUSED(fmi3GetClock, const fmi3ValueReference vr[], size_t nvr, fmi3Clock values[])
REFUSED(fmi3SetClock, const fmi3ValueReference vr[], size_t nvr, const fmi3Clock values[])
REFUSED(fmi3GetNumberOfVariableDependencies, fmi3ValueReference vr, size_t *n)
REFUSED(fmi3GetVariableDependencies, fmi3ValueReference dependent, size_t elements[],
        fmi3ValueReference independents[], size_t independentElements[],
        fmi3DependencyKind kinds[], size_t n)
REFUSED(fmi3GetFMUState, fmi3FMUState *state)
REFUSED(fmi3SetFMUState, fmi3FMUState state)
REFUSED(fmi3FreeFMUState, fmi3FMUState *state)
REFUSED(fmi3SerializedFMUStateSize, fmi3FMUState state, size_t *size)
REFUSED(fmi3SerializeFMUState, fmi3FMUState state, fmi3Byte bytes[], size_t size)
REFUSED(fmi3DeserializeFMUState, const fmi3Byte bytes[], size_t size, fmi3FMUState *state)
REFUSED(fmi3GetDirectionalDerivative, const fmi3ValueReference unknowns[], size_t nUnknowns,
        const fmi3ValueReference knowns[], size_t nKnowns, const fmi3Float64 seed[],
        size_t nSeed, fmi3Float64 sensitivity[], size_t nSensitivity)
REFUSED(fmi3GetAdjointDerivative, const fmi3ValueReference unknowns[], size_t nUnknowns,
        const fmi3ValueReference knowns[], size_t nKnowns, const fmi3Float64 seed[],
        size_t nSeed, fmi3Float64 sensitivity[], size_t nSensitivity)
REFUSED(fmi3GetOutputDerivatives, const fmi3ValueReference vr[], size_t nvr,
        const fmi3Int32 orders[], fmi3Float64 values[], size_t nValues)
REFUSED(fmi3GetIntervalDecimal, const fmi3ValueReference vr[], size_t nvr,
        fmi3Float64 intervals[], fmi3IntervalQualifier qualifiers[])
REFUSED(fmi3GetIntervalFraction, const fmi3ValueReference vr[], size_t nvr,
        fmi3UInt64 counters[], fmi3UInt64 resolutions[], fmi3IntervalQualifier qualifiers[])
REFUSED(fmi3GetShiftDecimal, const fmi3ValueReference vr[], size_t nvr, fmi3Float64 shifts[])
REFUSED(fmi3GetShiftFraction, const fmi3ValueReference vr[], size_t nvr, fmi3UInt64 counters[],
        fmi3UInt64 resolutions[])
REFUSED(fmi3SetIntervalDecimal, const fmi3ValueReference vr[], size_t nvr,
        const fmi3Float64 intervals[])
REFUSED(fmi3SetIntervalFraction, const fmi3ValueReference vr[], size_t nvr,
        const fmi3UInt64 counters[], const fmi3UInt64 resolutions[])
REFUSED(fmi3SetShiftDecimal, const fmi3ValueReference vr[], size_t nvr, const fmi3Float64 shifts[])
REFUSED(fmi3SetShiftFraction, const fmi3ValueReference vr[], size_t nvr,
        const fmi3UInt64 counters[], const fmi3UInt64 resolutions[])
REFUSED(fmi3ActivateModelPartition, fmi3ValueReference clock, fmi3Float64 activationTime)
REFUSED(fmi3DoStep, fmi3Float64 t, fmi3Float64 h, fmi3Boolean noSetPrior, fmi3Boolean *event,
        fmi3Boolean *terminate, fmi3Boolean *early, fmi3Float64 *last)
fmi3Status fmi3EnterConfigurationMode(fmi3Instance instance) { return fmi3Error; }
fmi3Status fmi3ExitConfigurationMode(fmi3Instance instance) { return fmi3Error; }
fmi3Status fmi3EnterStepMode(fmi3Instance instance) { return fmi3Error; }

fmi3Instance fmi3InstantiateCoSimulation(fmi3String name, fmi3String token, fmi3String resources,
                                         fmi3Boolean visible, fmi3Boolean loggingOn,
                                         fmi3Boolean eventModeUsed, fmi3Boolean earlyReturnAllowed,
                                         const fmi3ValueReference requiredIntermediateVariables[],
                                         size_t nRequiredIntermediateVariables,
                                         fmi3InstanceEnvironment environment,
                                         fmi3LogMessageCallback logMessage,
                                         fmi3IntermediateUpdateCallback intermediateUpdate) {
    return NULL; /* model exchange only */
}

fmi3Instance fmi3InstantiateScheduledExecution(fmi3String name, fmi3String token,
                                               fmi3String resources, fmi3Boolean visible,
                                               fmi3Boolean loggingOn,
                                               fmi3InstanceEnvironment environment,
                                               fmi3LogMessageCallback logMessage,
                                               fmi3ClockUpdateCallback clockUpdate,
                                               fmi3LockPreemptionCallback lockPreemption,
                                               fmi3UnlockPreemptionCallback unlockPreemption) {
    return NULL;
}
