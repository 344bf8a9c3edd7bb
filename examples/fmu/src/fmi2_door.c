/* The door as an FMI 2.0 FMU: every function of the standard's API, model exchange and
 * co-simulation in one binary. The work is done by door_model.c; this file turns the
 * FMI 2 calls into its calls and its statuses into fmi2Status. */
#include <string.h>

#include "door_model.h"
#include "fmi2Functions.h"

typedef struct {
    DoorInstance door; /* first, so that a DoorInstance* is a Fmi2Door* */
    fmi2CallbackFunctions callbacks;
    fmi2Boolean debug_logging;
} Fmi2Door;

#define DOOR(c) ((DoorInstance *)(c))
#define STATUS(expr) ((expr) == DOOR_OK ? fmi2OK : fmi2Error)
/* An FMI function the door does not offer: logged, fmi2Error. */
#define NOT_OFFERED(c, what) (door_error(DOOR(c), "%s is not offered by this FMU", what), fmi2Error)

static void log_error(const DoorInstance *door, const char *message) {
    const Fmi2Door *c = (const Fmi2Door *)door;
    if (c->callbacks.logger)
        c->callbacks.logger(c->callbacks.componentEnvironment, door->name, fmi2Error,
                            "logStatusError", "%s", message);
}

/* Logs through the host's callbacks before an instance exists. */
static void log_early(const fmi2CallbackFunctions *functions, const char *name, const char *message) {
    if (functions && functions->logger)
        functions->logger(functions->componentEnvironment, name ? name : "?", fmi2Error,
                          "logStatusError", "%s", message);
}

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }

const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[]) {
    if (!c) return fmi2Error;
    for (size_t i = 0; i < nCategories; i++)
        if (!categories || !categories[i] || strcmp(categories[i], "logStatusError") != 0)
            return NOT_OFFERED(c, "a log category other than logStatusError");
    ((Fmi2Door *)c)->debug_logging = loggingOn;
    return fmi2OK;
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation,
                              const fmi2CallbackFunctions *functions, fmi2Boolean visible,
                              fmi2Boolean loggingOn) {
    (void)fmuResourceLocation;
    (void)visible;
    if (!functions) return NULL;
    if (fmuType != fmi2ModelExchange && fmuType != fmi2CoSimulation) {
        log_early(functions, instanceName, "unknown fmuType");
        return NULL;
    }
    char why[DOOR_WHY_SIZE];
    Fmi2Door *c = (Fmi2Door *)door_new(sizeof(Fmi2Door), instanceName, fmuGUID,
                                       fmuType == fmi2CoSimulation, log_error, why);
    if (!c) {
        log_early(functions, instanceName, why);
        return NULL;
    }
    c->callbacks = *functions;
    c->debug_logging = loggingOn;
    return c;
}

void fmi2FreeInstance(fmi2Component c) { door_free(DOOR(c)); }

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined,
                               fmi2Real stopTime) {
    (void)toleranceDefined;
    (void)tolerance;
    (void)stopTimeDefined;
    (void)stopTime;
    if (door_require(DOOR(c), MODE_INSTANTIATED, "fmi2SetupExperiment")) return fmi2Error;
    DOOR(c)->s.time = startTime;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    if (!c) return fmi2Error;
    return STATUS(door_enter_initialization(DOOR(c), DOOR(c)->s.time));
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    return STATUS(door_exit_initialization(DOOR(c)));
}

fmi2Status fmi2Terminate(fmi2Component c) {
    if (door_require(DOOR(c), MODE_ANY & ~MODE_INSTANTIATED, "fmi2Terminate")) return fmi2Error;
    DOOR(c)->s.mode = MODE_TERMINATED;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component c) {
    if (!c) return fmi2Error;
    door_reset(DOOR(c));
    return fmi2OK;
}

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                       fmi2Real value[]) {
    return STATUS(door_get(DOOR(c), vr, nvr, value));
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                       const fmi2Real value[]) {
    return STATUS(door_set(DOOR(c), vr, nvr, value));
}

/* The door has Real variables only: any Integer, Boolean or String is unknown. */
#define NO_SUCH_TYPE(function, type, constness)                                            \
    fmi2Status function(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,         \
                        constness type value[]) {                                           \
        (void)vr;                                                                           \
        (void)value;                                                                        \
        return nvr == 0 ? fmi2OK : NOT_OFFERED(c, #function " of a value reference");       \
    }
NO_SUCH_TYPE(fmi2GetInteger, fmi2Integer, )
NO_SUCH_TYPE(fmi2GetBoolean, fmi2Boolean, )
NO_SUCH_TYPE(fmi2GetString, fmi2String, )
NO_SUCH_TYPE(fmi2SetInteger, fmi2Integer, const)
NO_SUCH_TYPE(fmi2SetBoolean, fmi2Boolean, const)
NO_SUCH_TYPE(fmi2SetString, fmi2String, const)

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    return STATUS(door_state_get(DOOR(c), FMUstate));
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate) {
    return STATUS(door_state_set(DOOR(c), FMUstate));
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    return STATUS(door_state_free(DOOR(c), FMUstate));
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate FMUstate, size_t *size) {
    (void)c;
    (void)FMUstate;
    if (!size) return fmi2Error;
    *size = door_state_size();
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate, fmi2Byte bytes[],
                                 size_t size) {
    return STATUS(door_state_serialize(DOOR(c), FMUstate, bytes, size));
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[], size_t size,
                                   fmi2FMUstate *FMUstate) {
    return STATUS(door_state_deserialize(DOOR(c), serializedState, size, FMUstate));
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown_ref[],
                                        size_t nUnknown, const fmi2ValueReference vKnown_ref[],
                                        size_t nKnown, const fmi2Real dvKnown[],
                                        fmi2Real dvUnknown[]) {
    (void)vUnknown_ref, (void)nUnknown, (void)vKnown_ref, (void)nKnown, (void)dvKnown;
    (void)dvUnknown;
    return NOT_OFFERED(c, "fmi2GetDirectionalDerivative");
}

/* Model exchange */

fmi2Status fmi2EnterEventMode(fmi2Component c) {
    if (door_require(DOOR(c), MODE_EVENT | MODE_CONTINUOUS, "fmi2EnterEventMode")) return fmi2Error;
    DOOR(c)->s.mode = MODE_EVENT;
    return fmi2OK;
}

fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *eventInfo) {
    if (door_require(DOOR(c), MODE_EVENT, "fmi2NewDiscreteStates")) return fmi2Error;
    if (!eventInfo) return fmi2Error;
    memset(eventInfo, 0, sizeof *eventInfo); /* no discrete states, no time events */
    return fmi2OK;
}

fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c) {
    if (door_require(DOOR(c), MODE_EVENT, "fmi2EnterContinuousTimeMode")) return fmi2Error;
    DOOR(c)->s.mode = MODE_CONTINUOUS;
    return fmi2OK;
}

fmi2Status fmi2CompletedIntegratorStep(fmi2Component c, fmi2Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi2Boolean *enterEventMode,
                                       fmi2Boolean *terminateSimulation) {
    (void)noSetFMUStatePriorToCurrentPoint;
    if (door_require(DOOR(c), MODE_CONTINUOUS, "fmi2CompletedIntegratorStep")) return fmi2Error;
    if (enterEventMode) *enterEventMode = fmi2False;
    if (terminateSimulation) *terminateSimulation = fmi2False;
    return fmi2OK;
}

fmi2Status fmi2SetTime(fmi2Component c, fmi2Real time) {
    return STATUS(door_set_time(DOOR(c), time));
}

fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t nx) {
    return STATUS(door_set_states(DOOR(c), x, nx));
}

fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real derivatives[], size_t nx) {
    return STATUS(door_get_derivatives(DOOR(c), derivatives, nx));
}

fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real eventIndicators[], size_t ni) {
    (void)eventIndicators;
    return STATUS(door_check_event_indicators(DOOR(c), ni));
}

fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t nx) {
    return STATUS(door_get_states(DOOR(c), x, nx));
}

fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x_nominal[], size_t nx) {
    return STATUS(door_get_nominals(DOOR(c), x_nominal, nx));
}

/* Co-simulation */

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    (void)vr, (void)nvr, (void)order, (void)value;
    return NOT_OFFERED(c, "fmi2SetRealInputDerivatives (canInterpolateInputs is false)");
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[]) {
    (void)vr, (void)nvr, (void)order, (void)value;
    return NOT_OFFERED(c, "fmi2GetRealOutputDerivatives (maxOutputDerivativeOrder is 0)");
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint,
                      fmi2Real communicationStepSize, fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    (void)noSetFMUStatePriorToCurrentPoint;
    return STATUS(door_do_step(DOOR(c), currentCommunicationPoint, communicationStepSize));
}

fmi2Status fmi2CancelStep(fmi2Component c) {
    return NOT_OFFERED(c, "fmi2CancelStep (fmi2DoStep never returns fmi2Pending)");
}

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value) {
    (void)s, (void)value;
    return NOT_OFFERED(c, "fmi2GetStatus (fmi2DoStep never returns fmi2Pending)");
}

/* The two status kinds a host may ask for after a DoStep that was not fmi2OK. */
static fmi2Status give_status(fmi2Component c, fmi2StatusKind s, fmi2StatusKind kind,
                              const char *function) {
    if (!c) return fmi2Error;
    if (s != kind) return NOT_OFFERED(c, function);
    return fmi2OK;
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value) {
    fmi2Status status = give_status(c, s, fmi2LastSuccessfulTime, "this fmi2GetRealStatus kind");
    if (status == fmi2OK && value) *value = DOOR(c)->s.time;
    return value ? status : fmi2Error;
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value) {
    (void)s, (void)value;
    return NOT_OFFERED(c, "fmi2GetIntegerStatus");
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value) {
    fmi2Status status = give_status(c, s, fmi2Terminated, "this fmi2GetBooleanStatus kind");
    if (status == fmi2OK && value) *value = fmi2False; /* the door never asks to stop */
    return value ? status : fmi2Error;
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value) {
    (void)s, (void)value;
    return NOT_OFFERED(c, "fmi2GetStringStatus");
}
