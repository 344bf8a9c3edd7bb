/* A hybrid door on a hinge: the FMU of tests/test_fmu_events.py, which exercises the
 * event handling of evo-door's model-exchange kernel. This half does not depend on the
 * FMI version; fmi2_hinge.c and fmi3_hinge.c wrap it.
 *
 * Continuous states theta (rad, 0 open, pi/2 closed) and omega (rad/s, + closing); input
 * force (N at the handle, + toward closing). Discrete states, changed only at events:
 *   latched        on when theta rises past latch_angle, off when the door is pulled
 *                  open to latch_angle - latch_play; while on, the catch pulls the door
 *                  shut with latch_torque (+ toward closing: it holds the door closed);
 *   damping_boost  on from release_time on (a time event): damping + boost_damping;
 * and a state reset: where the door reaches the open stop (theta = 0) moving open, it
 * bounces back, omega = -restitution * omega.
 *
 * hinge_variables.h (written by build.py from its one declaration) gives the value
 * references, the parameters' indices and their names, starts and bounds. */
#ifndef HINGE_H
#define HINGE_H

#include <stddef.h>

#include "hinge_variables.h"

#define HINGE_N_STATES 2

typedef enum {
    H_INSTANTIATED = 1,
    H_INITIALIZATION = 2,
    H_EVENT = 4,
    H_CONTINUOUS = 8,
    H_TERMINATED = 16
} HingeMode;

typedef struct Hinge {
    double time, theta, omega, force;
    double p[HINGE_N_PARAMETERS];
    int latched, damping_boost;
    HingeMode mode;
    /* the wrapper's logger: one line per refused call */
    void (*log)(const struct Hinge *h, const char *message);
} Hinge;

/* What one discrete-state update tells the importer. */
typedef struct {
    int states_changed;    /* the bounce reset omega */
    int next_time_defined; /* a time event is pending, at next_time */
    double next_time;
} HingeUpdate;

/* A zeroed block of `size` bytes (>= sizeof(Hinge): a wrapper puts its callbacks after
 * the Hinge it starts with), at the start values; NULL if the token is not this build's. */
Hinge *hinge_new(size_t size, const char *token);
void hinge_reset(Hinge *h);

/* 0 on success; otherwise the call is logged and refused (unknown value reference, a
 * value out of its declared range, a fixed parameter after initialization ...). */
int hinge_fail(const Hinge *h, const char *what, unsigned vr);
int hinge_get_real(const Hinge *h, unsigned vr, double *value);
int hinge_set_real(Hinge *h, unsigned vr, double value);
int hinge_get_boolean(const Hinge *h, unsigned vr, int *value);

/* Moves to mode `to` (0: stay) if the instance is in one of the modes `from` (a mask);
 * otherwise logs that `function` is not allowed now and returns 1. Leaving initialization
 * for event mode sets the discrete states from the start values. */
int hinge_move(Hinge *h, int from, HingeMode to, const char *function);

double hinge_accel(const Hinge *h);
void hinge_event_indicators(const Hinge *h, double z[HINGE_N_EVENT_INDICATORS]);
/* The arrays of model exchange: what hinge_states reads or writes. */
typedef enum {
    HINGE_SET_STATES,
    HINGE_GET_STATES,
    HINGE_GET_DERIVATIVES,
    HINGE_GET_NOMINALS,
    HINGE_GET_EVENT_INDICATORS
} HingeArray;
/* 0 on success; refused if `n` is not the array's length. */
int hinge_states(Hinge *h, HingeArray what, double v[], size_t n);
/* One discrete-state update at the current time and state (one pass settles them). */
void hinge_update(Hinge *h, HingeUpdate *u);

#endif
