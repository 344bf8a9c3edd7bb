/* The door's physics and the half of an FMU instance that does not depend on the FMI
 * version: values by value reference, modes, the co-simulation step, FMU states.
 * fmi2_door.c and fmi3_door.c wrap it in the two versions' functions.
 *
 * The value references, the parameters' names, starts and bounds come from
 * door_variables.h, which examples/fmu/build.py writes from its one declaration. */
#ifndef DOOR_MODEL_H
#define DOOR_MODEL_H

#include <stddef.h>

#include "door_variables.h"

/* The two continuous states: theta (rad, 0 open, pi/2 closed), omega (rad/s, + closing). */
#define DOOR_N_STATES 2

/* What a function of the door half returns; the wrappers turn it into fmi2/fmi3Status. */
typedef enum { DOOR_OK = 0, DOOR_ERROR = 1 } DoorStatus;

/* The FMI states an instance walks through (one enum for both versions and both kinds). */
typedef enum {
    MODE_INSTANTIATED = 1 << 0,
    MODE_INITIALIZATION = 1 << 1,
    MODE_EVENT = 1 << 2,      /* model exchange */
    MODE_CONTINUOUS = 1 << 3, /* model exchange */
    MODE_STEP = 1 << 4,       /* co-simulation */
    MODE_TERMINATED = 1 << 5,
} DoorMode;

#define MODE_BEFORE_INIT_DONE (MODE_INSTANTIATED | MODE_INITIALIZATION)
#define MODE_ANY 0x3f

/* Everything Get/SetFMUState copies and (De)SerializeFMUState writes. */
typedef struct {
    double time;
    double x[DOOR_N_STATES];
    double force;
    double p[DOOR_N_PARAMETERS];
    DoorMode mode;
} DoorState;

struct DoorInstance;

/* Hands an error message to the host's logger (the wrapper knows which one). */
typedef void (*DoorLog)(const struct DoorInstance *door, const char *message);

typedef struct DoorInstance {
    DoorState s;
    char *name;
    int co_simulation; /* 0: model exchange */
    DoorLog log;
} DoorInstance;

/* The right-hand side: the angular acceleration in rad/s2. */
double door_accel(const double p[], double theta, double omega, double force);

/* A zeroed block of `size` bytes (>= sizeof(DoorInstance); a wrapper puts its callbacks
 * after the DoorInstance it starts with), set to the start values. NULL on bad input,
 * with the reason in `why` for the wrapper to log (there is no instance to log through). */
#define DOOR_WHY_SIZE 256
DoorInstance *door_new(size_t size, const char *name, const char *token, int co_simulation,
                       DoorLog log, char why[DOOR_WHY_SIZE]);
void door_free(DoorInstance *door);
void door_reset(DoorInstance *door);

/* Logs an error (printf format) and returns DOOR_ERROR. */
DoorStatus door_error(const DoorInstance *door, const char *format, ...)
#if defined(__GNUC__)
    __attribute__((format(printf, 2, 3)))
#endif
    ;

/* DOOR_ERROR, logged, unless the instance is in one of the modes of `allowed`. */
DoorStatus door_require(const DoorInstance *door, int allowed, const char *function);

DoorStatus door_get(const DoorInstance *door, const unsigned vr[], size_t n, double value[]);
DoorStatus door_set(DoorInstance *door, const unsigned vr[], size_t n, const double value[]);

DoorStatus door_enter_initialization(DoorInstance *door, double start_time);
DoorStatus door_exit_initialization(DoorInstance *door);

/* Model exchange. */
DoorStatus door_set_time(DoorInstance *door, double time);
DoorStatus door_set_states(DoorInstance *door, const double x[], size_t nx);
DoorStatus door_get_states(const DoorInstance *door, double x[], size_t nx);
DoorStatus door_get_derivatives(const DoorInstance *door, double dx[], size_t nx);
DoorStatus door_get_nominals(const DoorInstance *door, double nominal[], size_t nx);
DoorStatus door_check_event_indicators(const DoorInstance *door, size_t ni);

/* Co-simulation: classical RK4 over [t, t + step] at h = step / ceil(step / max step),
 * the force held. */
DoorStatus door_do_step(DoorInstance *door, double t, double step);

/* FMU states: a copy of DoorState; its serialized form is a tag and the copy. */
DoorStatus door_state_get(const DoorInstance *door, void **state);
DoorStatus door_state_set(DoorInstance *door, const void *state);
DoorStatus door_state_free(const DoorInstance *door, void **state);
size_t door_state_size(void);
DoorStatus door_state_serialize(const DoorInstance *door, const void *state, char *bytes,
                                size_t size);
DoorStatus door_state_deserialize(const DoorInstance *door, const char *bytes, size_t size,
                                  void **state);

#endif
