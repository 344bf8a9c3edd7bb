/* The hinge's physics, discrete states and values by value reference (hinge.h). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "hinge.h"

static const HingeParameter PARAMETERS[HINGE_N_PARAMETERS] = HINGE_PARAMETER_TABLE;

#define P(name) (h->p[HINGE_P_##name])
#define HALF_PI 1.5707963267948966

Hinge *hinge_new(size_t size, const char *token) {
    if (size < sizeof(Hinge) || !token || strcmp(token, HINGE_TOKEN) != 0) return NULL;
    Hinge *h = calloc(1, size);
    if (h) hinge_reset(h);
    return h;
}

void hinge_reset(Hinge *h) {
    h->time = h->omega = h->force = 0.0;
    h->theta = HINGE_THETA_START;
    for (int i = 0; i < HINGE_N_PARAMETERS; i++) h->p[i] = PARAMETERS[i].start;
    h->latched = h->damping_boost = 0;
    h->mode = H_INSTANTIATED;
}

int hinge_fail(const Hinge *h, const char *what, unsigned vr) {
    char message[160];
    snprintf(message, sizeof message, "%s (value reference %u)", what, vr);
    if (h && h->log) h->log(h, message);
    return 1;
}

static void settle(Hinge *h) {
    if (!h->damping_boost && h->time >= P(RELEASE_TIME)) h->damping_boost = 1;
    /* >=: a solver that locates the crossing may stop with the indicator exactly 0 */
    if (!h->latched && h->theta >= P(LATCH_ANGLE))
        h->latched = 1;
    else if (h->latched && h->theta <= P(LATCH_ANGLE) - P(LATCH_PLAY))
        h->latched = 0;
}

int hinge_move(Hinge *h, int from, HingeMode to, const char *function) {
    if (!h) return 1;
    if (!(h->mode & from)) return hinge_fail(h, function, (unsigned)h->mode);
    if (h->mode == H_INITIALIZATION && to == H_EVENT) settle(h); /* the start's discrete states */
    if (to) h->mode = to;
    return 0;
}

double hinge_accel(const Hinge *h) {
    double damping = P(DAMPING) + (h->damping_boost ? P(BOOST_DAMPING) : 0.0);
    double torque = P(LEVER_ARM) * h->force + P(SPRING_PRELOAD)
                    + P(SPRING_STIFFNESS) * (HALF_PI - h->theta)
                    - P(WEIGHT_MOMENT) * cos(h->theta) - damping * h->omega
                    - P(FRICTION) * tanh(h->omega / P(FRICTION_SPEED));
    if (h->latched) torque += P(LATCH_TORQUE);
    /* the closed stop: a stiff spring and a damper while the door presses into it; no
     * event indicator (the law is continuous in theta), as many exported models do */
    if (h->theta > HALF_PI)
        torque -= P(STOP_STIFFNESS) * (h->theta - HALF_PI) + P(STOP_DAMPING) * h->omega;
    return torque / P(INERTIA);
}

void hinge_event_indicators(const Hinge *h, double z[HINGE_N_EVENT_INDICATORS]) {
    z[0] = h->theta - P(LATCH_ANGLE);                 /* the catch engages above 0 */
    z[1] = h->theta - (P(LATCH_ANGLE) - P(LATCH_PLAY)); /* it lets go at or below 0 */
    z[2] = h->theta;                                   /* the open stop */
}


void hinge_update(Hinge *h, HingeUpdate *u) {
    settle(h);
    u->states_changed = 0;
    if (h->theta <= 0.0 && h->omega < 0.0) {
        h->omega = -P(RESTITUTION) * h->omega;
        u->states_changed = 1;
    }
    u->next_time_defined = !h->damping_boost;
    u->next_time = P(RELEASE_TIME);
}

int hinge_get_real(const Hinge *h, unsigned vr, double *value) {
    double z[HINGE_N_EVENT_INDICATORS];
    hinge_event_indicators(h, z);
    switch (vr) {
    case HINGE_VR_TIME: *value = h->time; return 0;
    case HINGE_VR_THETA: *value = h->theta; return 0;
    case HINGE_VR_DTHETA: *value = h->omega; return 0;
    case HINGE_VR_DDTHETA: *value = hinge_accel(h); return 0;
    case HINGE_VR_FORCE: *value = h->force; return 0;
    case HINGE_VR_Z_LATCH: *value = z[0]; return 0;
    case HINGE_VR_Z_RELEASE: *value = z[1]; return 0;
    case HINGE_VR_Z_STOP: *value = z[2]; return 0;
    }
    if (vr >= HINGE_VR_FIRST_PARAMETER && vr < HINGE_VR_FIRST_PARAMETER + HINGE_N_PARAMETERS) {
        *value = h->p[vr - HINGE_VR_FIRST_PARAMETER];
        return 0;
    }
    return hinge_fail(h, "no real variable", vr);
}

int hinge_set_real(Hinge *h, unsigned vr, double value) {
    int before_init = h->mode == H_INSTANTIATED || h->mode == H_INITIALIZATION;
    if (!isfinite(value)) return hinge_fail(h, "a value that is not finite", vr);
    if (vr == HINGE_VR_FORCE) {
        h->force = value;
        return 0;
    }
    if ((vr == HINGE_VR_THETA || vr == HINGE_VR_DTHETA) && before_init) {
        *(vr == HINGE_VR_THETA ? &h->theta : &h->omega) = value;
        return 0;
    }
    if (vr < HINGE_VR_FIRST_PARAMETER || vr >= HINGE_VR_FIRST_PARAMETER + HINGE_N_PARAMETERS)
        return hinge_fail(h, "no settable real variable", vr);
    const HingeParameter *q = &PARAMETERS[vr - HINGE_VR_FIRST_PARAMETER];
    if (q->fixed && !before_init) return hinge_fail(h, "a fixed parameter after initialization", vr);
    if (value < q->min || value > q->max) return hinge_fail(h, "a value outside [min, max]", vr);
    h->p[vr - HINGE_VR_FIRST_PARAMETER] = value;
    return 0;
}

int hinge_get_boolean(const Hinge *h, unsigned vr, int *value) {
    if (vr == HINGE_VR_LATCHED) *value = h->latched;
    else if (vr == HINGE_VR_DAMPING_BOOST) *value = h->damping_boost;
    else return hinge_fail(h, "no boolean variable", vr);
    return 0;
}

int hinge_states(Hinge *h, HingeArray what, double v[], size_t n) {
    size_t want = what == HINGE_GET_EVENT_INDICATORS ? HINGE_N_EVENT_INDICATORS : HINGE_N_STATES;
    if (n != want) return hinge_fail(h, "an array of the wrong length", (unsigned)n);
    switch (what) {
    case HINGE_SET_STATES: h->theta = v[0], h->omega = v[1]; break;
    case HINGE_GET_STATES: v[0] = h->theta, v[1] = h->omega; break;
    case HINGE_GET_DERIVATIVES: v[0] = h->omega, v[1] = hinge_accel(h); break;
    case HINGE_GET_NOMINALS: v[0] = v[1] = 1.0; break;
    case HINGE_GET_EVENT_INDICATORS: hinge_event_indicators(h, v); break;
    }
    return 0;
}
