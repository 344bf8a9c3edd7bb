/* The hinge (hinge.h) as an FMI 2.0 model-exchange FMU. */
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "hinge.h"

typedef struct {
    Hinge h; /* first: a Hinge* is a Fmi2Hinge* */
    fmi2CallbackFunctions callbacks;
} Fmi2Hinge;

#define H(c) ((Hinge *)(c))
#define STATUS(failed) ((failed) ? fmi2Error : fmi2OK)

static void log_to_host(const Hinge *h, const char *message) {
    const Fmi2Hinge *c = (const Fmi2Hinge *)h;
    if (c->callbacks.logger)
        c->callbacks.logger(c->callbacks.componentEnvironment, "hinge", fmi2Error,
                            "logStatusError", "%s", message);
}

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid,
                              fmi2String resources, const fmi2CallbackFunctions *functions,
                              fmi2Boolean visible, fmi2Boolean loggingOn) {
    (void)name, (void)resources, (void)visible, (void)loggingOn;
    if (type != fmi2ModelExchange || !functions) return NULL;
    Fmi2Hinge *c = (Fmi2Hinge *)hinge_new(sizeof(Fmi2Hinge), guid);
    if (!c) return NULL;
    c->callbacks = *functions;
    c->h.log = log_to_host;
    return c;
}

void fmi2FreeInstance(fmi2Component c) { free(c); }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n, const fmi2String k[]) {
    (void)on, (void)k;
    return STATUS(!c || n > 0);
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime) {
    (void)toleranceDefined, (void)tolerance, (void)stopTimeDefined, (void)stopTime;
    if (hinge_move(H(c), H_INSTANTIATED, 0, "fmi2SetupExperiment")) return fmi2Error;
    H(c)->time = startTime;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    return STATUS(hinge_move(H(c), H_INSTANTIATED, H_INITIALIZATION, "fmi2EnterInitializationMode"));
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    return STATUS(hinge_move(H(c), H_INITIALIZATION, H_EVENT, "fmi2ExitInitializationMode"));
}

fmi2Status fmi2Terminate(fmi2Component c) {
    return STATUS(hinge_move(H(c), H_EVENT | H_CONTINUOUS, H_TERMINATED, "fmi2Terminate"));
}

fmi2Status fmi2Reset(fmi2Component c) {
    if (!c) return fmi2Error;
    hinge_reset(H(c));
    return fmi2OK;
}

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real v[]) {
    int failed = !c;
    for (size_t i = 0; i < n && !failed; i++) failed = hinge_get_real(H(c), vr[i], &v[i]);
    return STATUS(failed);
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                       const fmi2Real v[]) {
    int failed = !c;
    for (size_t i = 0; i < n && !failed; i++) failed = hinge_set_real(H(c), vr[i], v[i]);
    return STATUS(failed);
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                          fmi2Boolean v[]) {
    int failed = !c;
    for (size_t i = 0; i < n && !failed; i++) failed = hinge_get_boolean(H(c), vr[i], &v[i]);
    return STATUS(failed);
}

/* No Integer or String variables; Booleans are outputs only: an empty call succeeds. */
#define NO_SUCH_VARIABLES(function, type)                                                    \
    fmi2Status function(fmi2Component c, const fmi2ValueReference vr[], size_t n, type v[]) { \
        (void)vr, (void)v;                                                                   \
        return STATUS(!c || n > 0);                                                          \
    }
NO_SUCH_VARIABLES(fmi2GetInteger, fmi2Integer)
NO_SUCH_VARIABLES(fmi2SetInteger, const fmi2Integer)
NO_SUCH_VARIABLES(fmi2SetBoolean, const fmi2Boolean)
NO_SUCH_VARIABLES(fmi2GetString, fmi2String)
NO_SUCH_VARIABLES(fmi2SetString, const fmi2String)

/* Not offered (canGetAndSetFMUstate, providesDirectionalDerivative are false). */
fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *s) { (void)c, (void)s; return fmi2Error; }
fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate s) { (void)c, (void)s; return fmi2Error; }
fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *s) { (void)c, (void)s; return fmi2Error; }
fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate s, size_t *n) {
    (void)c, (void)s, (void)n;
    return fmi2Error;
}
fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate s, fmi2Byte b[], size_t n) {
    (void)c, (void)s, (void)b, (void)n;
    return fmi2Error;
}
fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte b[], size_t n, fmi2FMUstate *s) {
    (void)c, (void)s, (void)b, (void)n;
    return fmi2Error;
}
fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference u[], size_t nu,
                                        const fmi2ValueReference k[], size_t nk,
                                        const fmi2Real dk[], fmi2Real du[]) {
    (void)c, (void)u, (void)nu, (void)k, (void)nk, (void)dk, (void)du;
    return fmi2Error;
}

/* Model exchange */

fmi2Status fmi2EnterEventMode(fmi2Component c) {
    return STATUS(hinge_move(H(c), H_EVENT | H_CONTINUOUS, H_EVENT, "fmi2EnterEventMode"));
}

fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *info) {
    if (hinge_move(H(c), H_EVENT, 0, "fmi2NewDiscreteStates") || !info) return fmi2Error;
    HingeUpdate u;
    hinge_update(H(c), &u);
    memset(info, 0, sizeof *info);
    info->valuesOfContinuousStatesChanged = u.states_changed ? fmi2True : fmi2False;
    info->nextEventTimeDefined = u.next_time_defined ? fmi2True : fmi2False;
    info->nextEventTime = u.next_time;
    return fmi2OK;
}

fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c) {
    return STATUS(hinge_move(H(c), H_EVENT, H_CONTINUOUS, "fmi2EnterContinuousTimeMode"));
}

fmi2Status fmi2CompletedIntegratorStep(fmi2Component c, fmi2Boolean noSetPrior,
                                       fmi2Boolean *enterEventMode, fmi2Boolean *terminate) {
    (void)noSetPrior;
    if (hinge_move(H(c), H_CONTINUOUS, 0, "fmi2CompletedIntegratorStep")) return fmi2Error;
    *enterEventMode = fmi2False;
    *terminate = fmi2False;
    return fmi2OK;
}

fmi2Status fmi2SetTime(fmi2Component c, fmi2Real time) {
    if (!c) return fmi2Error;
    H(c)->time = time;
    return fmi2OK;
}

fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t nx) {
    return STATUS(!c || hinge_states(H(c), HINGE_SET_STATES, (double *)x, nx));
}

fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t nx) {
    return STATUS(!c || hinge_states(H(c), HINGE_GET_STATES, x, nx));
}

fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real dx[], size_t nx) {
    return STATUS(!c || hinge_states(H(c), HINGE_GET_DERIVATIVES, dx, nx));
}

fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real z[], size_t nz) {
    return STATUS(!c || hinge_states(H(c), HINGE_GET_EVENT_INDICATORS, z, nz));
}

fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real nominal[], size_t nx) {
    return STATUS(!c || hinge_states(H(c), HINGE_GET_NOMINALS, nominal, nx));
}
