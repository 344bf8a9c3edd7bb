/* The door's physics and the version-independent half of an instance (door_model.h). */
#include "door_model.h"

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define HALF_PI 1.57079632679489661923
#define DEG_PER_RAD 57.29577951308232

/* The one place with the equation of motion (docs/conventions.md: theta 0 open, pi/2
 * closed; torques + toward closing). The dry friction is smoothed with tanh so that
 * the right-hand side stays continuous; the end stops are penalty springs with damping
 * that acts only while the door is past a stop. */
double door_accel(const double p[], double theta, double omega, double force) {
    double torque = p[DOOR_P_LEVER_ARM] * force                       /* the hand */
                    + p[DOOR_P_SPRING_PRELOAD]                        /* spring at closed */
                    + p[DOOR_P_SPRING_STIFFNESS] * (HALF_PI - theta)  /* more when open */
                    - p[DOOR_P_WEIGHT_MOMENT] * cos(theta)            /* weight pulls open */
                    - p[DOOR_P_DAMPING] * omega
                    - p[DOOR_P_FRICTION] * tanh(omega / p[DOOR_P_FRICTION_SPEED]);
    if (theta < 0.0) {
        torque += -p[DOOR_P_STOP_STIFFNESS] * theta - p[DOOR_P_STOP_DAMPING] * omega;
    } else if (theta > HALF_PI) {
        torque += -p[DOOR_P_STOP_STIFFNESS] * (theta - HALF_PI) - p[DOOR_P_STOP_DAMPING] * omega;
    }
    return torque / p[DOOR_P_INERTIA];
}

DoorStatus door_error(const DoorInstance *door, const char *format, ...) {
    char message[512];
    va_list args;
    va_start(args, format);
    vsnprintf(message, sizeof message, format, args);
    va_end(args);
    if (door && door->log) door->log(door, message);
    return DOOR_ERROR;
}

#ifdef DOOR_FAULTS
#include <signal.h>
#ifdef _WIN32
#include <windows.h>
static void door_sleep(void) { Sleep(1000); }
#else
#include <unistd.h>
static void door_sleep(void) { sleep(1); }
#endif

/* A test fixture, compiled only with -DDOOR_FAULTS (build.py --faults): the door
 * misbehaves on purpose for damping values a test picks (the thresholds are build.py's
 * FAULTS, written into door_variables.h), so that a host can be shown to survive an FMU
 * that crashes, hangs or fails. Called where the work is: the derivatives and DoStep. */
static DoorStatus door_fault(const DoorInstance *door, const char *function) {
    const double damping = door->s.p[DOOR_P_DAMPING];
    if (damping > DOOR_FAULT_CRASH_ABOVE) {
        volatile int *nowhere = NULL;
        *nowhere = 1;  /* a segmentation fault, as a real bug would give */
        raise(SIGSEGV); /* in case page 0 is mapped */
    }
    if (damping > DOOR_FAULT_HANG_ABOVE) {
        /* never returns; asleep, so that each hang a test provokes costs the host's time
         * limit and not a core besides (the host cannot tell it from a busy loop: both
         * are a call that does not come back) */
        for (;;) door_sleep();
    }
    if (damping > DOOR_FAULT_ERROR_ABOVE)
        return door_error(door, "%s: damping = %g N.m.s/rad is a fault on purpose (DOOR_FAULTS)",
                          function, damping);
    return DOOR_OK;
}
#define DOOR_FAULT(door, function)                                  \
    do {                                                            \
        if (door_fault(door, function) != DOOR_OK) return DOOR_ERROR; \
    } while (0)
#else
#define DOOR_FAULT(door, function) ((void)0)
#endif

DoorStatus door_require(const DoorInstance *door, int allowed, const char *function) {
    if (!door) return DOOR_ERROR;
    if (door->s.mode & allowed) return DOOR_OK;
    return door_error(door, "%s is not allowed in this state of the FMU (mode %d)", function,
                      (int)door->s.mode);
}

void door_reset(DoorInstance *door) {
    memset(&door->s, 0, sizeof door->s);
    for (int i = 0; i < DOOR_N_PARAMETERS; i++) door->s.p[i] = door_parameters[i].start;
    door->s.mode = MODE_INSTANTIATED;
}

DoorInstance *door_new(size_t size, const char *name, const char *token, int co_simulation,
                       DoorLog log, char why[DOOR_WHY_SIZE]) {
    why[0] = '\0';
    if (!name || !*name) {
        snprintf(why, DOOR_WHY_SIZE, "the instance name must not be empty");
        return NULL;
    }
    if (!token || strcmp(token, DOOR_TOKEN) != 0) {
        snprintf(why, DOOR_WHY_SIZE, "token %.80s does not match this FMU's %s",
                 token ? token : "(null)", DOOR_TOKEN);
        return NULL;
    }
    if ((co_simulation && !DOOR_CO_SIMULATION) || (!co_simulation && !DOOR_MODEL_EXCHANGE)) {
        snprintf(why, DOOR_WHY_SIZE, "this FMU was built without %s",
                 co_simulation ? "co-simulation" : "model exchange");
        return NULL;
    }
    DoorInstance *door = calloc(1, size < sizeof *door ? sizeof *door : size);
    if (door) door->name = malloc(strlen(name) + 1);
    if (!door || !door->name) {
        free(door);
        snprintf(why, DOOR_WHY_SIZE, "out of memory");
        return NULL;
    }
    strcpy(door->name, name);
    door->co_simulation = co_simulation;
    door->log = log;
    door_reset(door);
    return door;
}

void door_free(DoorInstance *door) {
    if (!door) return;
    free(door->name);
    free(door);
}

static const char *name_of(unsigned vr) {
    if (vr < DOOR_VR_FIRST_PARAMETER) return door_signal_names[vr];
    if (vr - DOOR_VR_FIRST_PARAMETER < DOOR_N_PARAMETERS)
        return door_parameters[vr - DOOR_VR_FIRST_PARAMETER].name;
    return NULL;
}

static DoorStatus unknown(const DoorInstance *door, unsigned vr) {
    return door_error(door, "unknown value reference %u", vr);
}

static DoorStatus get_one(const DoorInstance *door, unsigned vr, double *value) {
    const DoorState *s = &door->s;
    if (!name_of(vr)) return unknown(door, vr);
    switch (vr) {
        case DOOR_VR_TIME: *value = s->time; return DOOR_OK;
        case DOOR_VR_THETA: *value = s->x[0]; return DOOR_OK;
        case DOOR_VR_OMEGA:
        case DOOR_VR_DER_THETA: *value = s->x[1]; return DOOR_OK;
        case DOOR_VR_ACCEL: *value = door_accel(s->p, s->x[0], s->x[1], s->force); return DOOR_OK;
        case DOOR_VR_FORCE: *value = s->force; return DOOR_OK;
        case DOOR_VR_ANGLE: *value = s->x[0] * DEG_PER_RAD; return DOOR_OK;
        case DOOR_VR_SPEED: *value = s->x[1] * DEG_PER_RAD; return DOOR_OK;
        default: *value = s->p[vr - DOOR_VR_FIRST_PARAMETER]; return DOOR_OK;
    }
}

DoorStatus door_get(const DoorInstance *door, const unsigned vr[], size_t n, double value[]) {
    if (!door) return DOOR_ERROR;
    if (n > 0 && (!vr || !value)) return door_error(door, "get: NULL array");
    for (size_t i = 0; i < n; i++)
        if (get_one(door, vr[i], &value[i]) != DOOR_OK) return DOOR_ERROR;
    return DOOR_OK;
}

static DoorStatus set_parameter(DoorInstance *door, unsigned index, double value) {
    const DoorParameter *p = &door_parameters[index];
    if (p->fixed && !(door->s.mode & MODE_BEFORE_INIT_DONE))
        return door_error(door, "%s is a fixed parameter: set it before initialization ends",
                          p->name);
    if (!(value >= p->min && value <= p->max))
        return door_error(door, "%s = %g is outside [%g, %g]", p->name, value, p->min, p->max);
    door->s.p[index] = value;
    return DOOR_OK;
}

static DoorStatus set_one(DoorInstance *door, unsigned vr, double value) {
    const char *name = name_of(vr);
    if (!name) return unknown(door, vr);
    if (!isfinite(value)) return door_error(door, "%s = %g is not a finite number", name, value);
    if (door->s.mode == MODE_TERMINATED) return door_error(door, "set %s: terminated", name);
    if (vr >= DOOR_VR_FIRST_PARAMETER) return set_parameter(door, vr - DOOR_VR_FIRST_PARAMETER, value);
    if (vr == DOOR_VR_FORCE) {
        door->s.force = value;
        return DOOR_OK;
    }
    if (vr == DOOR_VR_THETA || vr == DOOR_VR_OMEGA) {
        /* start values of the states; afterwards the states move by SetContinuousStates */
        if (!(door->s.mode & MODE_BEFORE_INIT_DONE))
            return door_error(door, "%s is a state: set it before initialization ends", name);
        door->s.x[vr == DOOR_VR_OMEGA] = value;
        return DOOR_OK;
    }
    return door_error(door, "%s is calculated by the FMU and cannot be set", name);
}

DoorStatus door_set(DoorInstance *door, const unsigned vr[], size_t n, const double value[]) {
    if (!door) return DOOR_ERROR;
    if (n > 0 && (!vr || !value)) return door_error(door, "set: NULL array");
    for (size_t i = 0; i < n; i++)
        if (set_one(door, vr[i], value[i]) != DOOR_OK) return DOOR_ERROR;
    return DOOR_OK;
}

DoorStatus door_enter_initialization(DoorInstance *door, double start_time) {
    if (door_require(door, MODE_INSTANTIATED, "EnterInitializationMode")) return DOOR_ERROR;
    if (!isfinite(start_time)) return door_error(door, "start time %g s", start_time);
    door->s.time = start_time;
    door->s.mode = MODE_INITIALIZATION;
    return DOOR_OK;
}

DoorStatus door_exit_initialization(DoorInstance *door) {
    if (door_require(door, MODE_INITIALIZATION, "ExitInitializationMode")) return DOOR_ERROR;
    door->s.mode = door->co_simulation ? MODE_STEP : MODE_EVENT;
    return DOOR_OK;
}

static DoorStatus check_states(const DoorInstance *door, const void *x, size_t nx) {
    if (!door) return DOOR_ERROR;
    if (!x) return door_error(door, "NULL state array");
    if (nx != DOOR_N_STATES)
        return door_error(door, "%zu continuous states asked for, the door has %d", nx,
                          DOOR_N_STATES);
    return DOOR_OK;
}

DoorStatus door_set_time(DoorInstance *door, double time) {
    if (door_require(door, MODE_EVENT | MODE_CONTINUOUS, "SetTime")) return DOOR_ERROR;
    if (!isfinite(time)) return door_error(door, "SetTime: %g s is not finite", time);
    door->s.time = time;
    return DOOR_OK;
}

DoorStatus door_set_states(DoorInstance *door, const double x[], size_t nx) {
    if (door_require(door, MODE_CONTINUOUS | MODE_EVENT, "SetContinuousStates") ||
        check_states(door, x, nx))
        return DOOR_ERROR;
    if (!isfinite(x[0]) || !isfinite(x[1]))
        return door_error(door, "SetContinuousStates: theta = %g rad, omega = %g rad/s", x[0],
                          x[1]);
    door->s.x[0] = x[0];
    door->s.x[1] = x[1];
    return DOOR_OK;
}

DoorStatus door_get_states(const DoorInstance *door, double x[], size_t nx) {
    if (check_states(door, x, nx)) return DOOR_ERROR;
    x[0] = door->s.x[0];
    x[1] = door->s.x[1];
    return DOOR_OK;
}

DoorStatus door_get_derivatives(const DoorInstance *door, double dx[], size_t nx) {
    if (check_states(door, dx, nx)) return DOOR_ERROR;
    DOOR_FAULT(door, "GetDerivatives");
    const DoorState *s = &door->s;
    dx[0] = s->x[1];
    dx[1] = door_accel(s->p, s->x[0], s->x[1], s->force);
    return DOOR_OK;
}

DoorStatus door_get_nominals(const DoorInstance *door, double nominal[], size_t nx) {
    if (check_states(door, nominal, nx)) return DOOR_ERROR;
    nominal[0] = 1.0;
    nominal[1] = 1.0;
    return DOOR_OK;
}

DoorStatus door_check_event_indicators(const DoorInstance *door, size_t ni) {
    if (!door) return DOOR_ERROR;
    if (ni != 0) return door_error(door, "%zu event indicators asked for, the door has none", ni);
    return DOOR_OK;
}

DoorStatus door_do_step(DoorInstance *door, double t, double step) {
    if (door_require(door, MODE_STEP, "DoStep")) return DOOR_ERROR;
    DoorState *s = &door->s;
    if (!(step >= 0.0) || !isfinite(step))
        return door_error(door, "DoStep: step %g s must be finite and not negative", step);
    if (fabs(t - s->time) > 1e-9 * fmax(1.0, fabs(t)))
        return door_error(door, "DoStep from t = %.17g s but the FMU is at %.17g s", t, s->time);
    DOOR_FAULT(door, "DoStep");
    /* the slack keeps a step that is a whole number of max steps from taking one more */
    long n = (long)ceil(step / DOOR_RK4_MAX_STEP * (1.0 - 1e-12));
    if (n < 1) n = 1;
    const double h = step / (double)n, f = s->force;
    double th = s->x[0], om = s->x[1];
    for (long i = 0; i < n; i++) {
        const double k1t = om, k1o = door_accel(s->p, th, om, f);
        const double k2t = om + 0.5 * h * k1o;
        const double k2o = door_accel(s->p, th + 0.5 * h * k1t, k2t, f);
        const double k3t = om + 0.5 * h * k2o;
        const double k3o = door_accel(s->p, th + 0.5 * h * k2t, k3t, f);
        const double k4t = om + h * k3o;
        const double k4o = door_accel(s->p, th + h * k3t, k4t, f);
        th += h / 6.0 * (k1t + 2.0 * k2t + 2.0 * k3t + k4t);
        om += h / 6.0 * (k1o + 2.0 * k2o + 2.0 * k3o + k4o);
    }
    s->x[0] = th;
    s->x[1] = om;
    s->time = t + step;
    return DOOR_OK;
}

/* The serialized form starts with this tag, so that bytes of another FMU are refused. */
static const char STATE_TAG[8] = "DOOR1\0\0";

DoorStatus door_state_get(const DoorInstance *door, void **state) {
    if (!door) return DOOR_ERROR;
    if (!state) return door_error(door, "GetFMUState: NULL pointer");
    if (!*state) *state = malloc(sizeof(DoorState));
    if (!*state) return door_error(door, "GetFMUState: out of memory");
    memcpy(*state, &door->s, sizeof(DoorState));
    return DOOR_OK;
}

DoorStatus door_state_set(DoorInstance *door, const void *state) {
    if (!door) return DOOR_ERROR;
    if (!state) return door_error(door, "SetFMUState: NULL state");
    memcpy(&door->s, state, sizeof(DoorState));
    return DOOR_OK;
}

DoorStatus door_state_free(const DoorInstance *door, void **state) {
    (void)door;
    if (state) {
        free(*state);
        *state = NULL;
    }
    return DOOR_OK;
}

size_t door_state_size(void) { return sizeof STATE_TAG + sizeof(DoorState); }

DoorStatus door_state_serialize(const DoorInstance *door, const void *state, char *bytes,
                                size_t size) {
    if (!state || !bytes || size != door_state_size())
        return door_error(door, "SerializeFMUState: %zu bytes, expected %zu", size,
                          door_state_size());
    memcpy(bytes, STATE_TAG, sizeof STATE_TAG);
    memcpy(bytes + sizeof STATE_TAG, state, sizeof(DoorState));
    return DOOR_OK;
}

DoorStatus door_state_deserialize(const DoorInstance *door, const char *bytes, size_t size,
                                  void **state) {
    if (!bytes || size != door_state_size() || memcmp(bytes, STATE_TAG, sizeof STATE_TAG) != 0)
        return door_error(door, "DeserializeFMUState: not a state of this FMU (%zu bytes)", size);
    if (door_state_get(door, state)) return DOOR_ERROR;
    memcpy(*state, bytes + sizeof STATE_TAG, sizeof(DoorState));
    return DOOR_OK;
}
