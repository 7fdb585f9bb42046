/*
 * Unicycle: an FMI 2.0 Co-Simulation FMU of a planar vehicle with first-order speed and yaw-rate
 * lags in a uniform current (hptvsim test FMU; see typed_fmu.h and tests/cosim/vehicle_fmus.py).
 * It stands for an "external vehicle FMU": a model written by someone else, with variable names
 * of its own.
 *
 *   parameters (fixed): north0, east0 [m], heading0 [rad]: the initial pose;
 *                       lag [s] (start 0.5, must be > 0): the time constant of u and r;
 *   inputs:             speed_cmd [m/s], turn_rate_cmd [rad/s]: the commanded surge speed
 *                       through the water and yaw rate;
 *                       drift_n, drift_e [m/s]: the current (north, east; earth frame);
 *   state:              n, e [m], psi [rad], u [m/s] (surge speed through the water),
 *                       r [rad/s] (yaw rate); n = north0, e = east0, psi = heading0, u = r = 0
 *                       at fmi2ExitInitializationMode;
 *   ODE:                du/dt = (speed_cmd - u) / lag        dr/dt = (turn_rate_cmd - r) / lag
 *                       dn/dt = u cos(psi) + drift_n         de/dt = u sin(psi) + drift_e
 *                       dpsi/dt = r
 *   outputs:            north = n, east = e, heading = psi wrapped to [-pi, pi),
 *                       surge = u + drift_n cos(psi) + drift_e sin(psi)  (speed over ground
 *                       along the body x axis), sway = -drift_n sin(psi) + drift_e cos(psi),
 *                       yaw_rate = r.
 *
 * fmi2DoStep(h) integrates with the classical Runge-Kutta method, the inputs held over the step,
 * in n = ceil(h / 0.01 - 1e-9) equal sub-steps of h / n (at least one; a step that would take
 * more than 1e9 sub-steps is discarded without advancing). The outputs are computed
 * on every read (fmi2GetReal) from the state and the current inputs: in initialization mode the
 * state is the initial one of the current parameters, and surge and sway follow the drift inputs
 * at once (direct feedthrough). A lag <= 0 (or NaN) is rejected by fmi2SetReal with fmi2Error.
 */
#define MODEL_NAME "Unicycle"

typedef struct {
    double north0, east0, heading0, lag;               /* parameters */
    double speed_cmd, turn_rate_cmd, drift_n, drift_e; /* inputs */
    double north, east, heading, surge, sway, yaw_rate; /* outputs */
    double x[5];                                       /* state: n, e, psi, u, r */
} model_data;

#include "typed_fmu.h"

enum { X_N, X_E, X_PSI, X_U, X_R, N_STATES };

#define UNICYCLE_PI 3.14159265358979323846 /* M_PI is not C99 */
#define MAX_SUBSTEP 0.01                   /* s: the longest internal Runge-Kutta step */
#define MAX_SUBSTEPS 1e9                   /* per fmi2DoStep: a longer step is discarded */
#define SMALLEST_POSITIVE 0x1p-1074        /* lag > 0: fmi2SetReal checks min <= lag */

static const char *const *model_guid_list(void) {
    static const char *const guids[] = {"{0c4e9a57-3b1d-4f62-a8e0-5d7b2c9f1e36}", NULL};
    return guids;
}

static const var_info *model_variables(size_t *n) {
    static const var_info vars[] = {
        {"north0", 0, T_REAL, K_FIXED, FIELD(north0), NO_LIMITS},
        {"east0", 1, T_REAL, K_FIXED, FIELD(east0), NO_LIMITS},
        {"heading0", 2, T_REAL, K_FIXED, FIELD(heading0), NO_LIMITS},
        {"lag", 3, T_REAL, K_FIXED, FIELD(lag), SMALLEST_POSITIVE, HUGE_VAL},
        {"speed_cmd", 10, T_REAL, K_INPUT, FIELD(speed_cmd), NO_LIMITS},
        {"turn_rate_cmd", 11, T_REAL, K_INPUT, FIELD(turn_rate_cmd), NO_LIMITS},
        {"drift_n", 12, T_REAL, K_INPUT, FIELD(drift_n), NO_LIMITS},
        {"drift_e", 13, T_REAL, K_INPUT, FIELD(drift_e), NO_LIMITS},
        {"north", 20, T_REAL, K_OUTPUT, FIELD(north), NO_LIMITS},
        {"east", 21, T_REAL, K_OUTPUT, FIELD(east), NO_LIMITS},
        {"heading", 22, T_REAL, K_OUTPUT, FIELD(heading), NO_LIMITS},
        {"surge", 23, T_REAL, K_OUTPUT, FIELD(surge), NO_LIMITS},
        {"sway", 24, T_REAL, K_OUTPUT, FIELD(sway), NO_LIMITS},
        {"yaw_rate", 25, T_REAL, K_OUTPUT, FIELD(yaw_rate), NO_LIMITS},
    };
    *n = sizeof vars / sizeof vars[0];
    return vars;
}

static void initial_state(model_data *m) {
    m->x[X_N] = m->north0;
    m->x[X_E] = m->east0;
    m->x[X_PSI] = m->heading0;
    m->x[X_U] = 0.0;
    m->x[X_R] = 0.0;
}

static void model_start(model_data *m) {
    memset(m, 0, sizeof *m);
    m->lag = 0.5;
    initial_state(m);
}

/* psi wrapped to [-pi, pi) (the guards catch rounding at the ends of the interval). */
static double wrap_angle(double psi) {
    const double two_pi = 2.0 * UNICYCLE_PI;
    double w = psi - two_pi * floor((psi + UNICYCLE_PI) / two_pi);
    if (w >= UNICYCLE_PI) w -= two_pi;
    if (w < -UNICYCLE_PI) w += two_pi;
    return w;
}

static void compute_outputs(model_data *m) {
    const double c = cos(m->x[X_PSI]), s = sin(m->x[X_PSI]);
    m->north = m->x[X_N];
    m->east = m->x[X_E];
    m->heading = wrap_angle(m->x[X_PSI]);
    m->surge = m->x[X_U] + m->drift_n * c + m->drift_e * s;
    m->sway = -m->drift_n * s + m->drift_e * c;
    m->yaw_rate = m->x[X_R];
}

/* Before fmi2ExitInitializationMode the state is the initial one of the current parameters. */
static void model_refresh(fmu_instance *in) {
    if (in->s.mode & (M_INSTANTIATED | M_INIT)) initial_state(&in->s.m);
    compute_outputs(&in->s.m);
}

static void model_exit_init(fmu_instance *in) {
    initial_state(&in->s.m);
    compute_outputs(&in->s.m);
}

static void derivatives(const model_data *m, const double x[N_STATES], double dx[N_STATES]) {
    dx[X_N] = x[X_U] * cos(x[X_PSI]) + m->drift_n;
    dx[X_E] = x[X_U] * sin(x[X_PSI]) + m->drift_e;
    dx[X_PSI] = x[X_R];
    dx[X_U] = (m->speed_cmd - x[X_U]) / m->lag;
    dx[X_R] = (m->turn_rate_cmd - x[X_R]) / m->lag;
}

/* One classical Runge-Kutta step of size dt, the inputs held. */
static void rk4_step(model_data *m, double dt) {
    double k1[N_STATES], k2[N_STATES], k3[N_STATES], k4[N_STATES], y[N_STATES];
    int i;
    derivatives(m, m->x, k1);
    for (i = 0; i < N_STATES; i++) y[i] = m->x[i] + 0.5 * dt * k1[i];
    derivatives(m, y, k2);
    for (i = 0; i < N_STATES; i++) y[i] = m->x[i] + 0.5 * dt * k2[i];
    derivatives(m, y, k3);
    for (i = 0; i < N_STATES; i++) y[i] = m->x[i] + dt * k3[i];
    derivatives(m, y, k4);
    for (i = 0; i < N_STATES; i++) m->x[i] += dt / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
}

static fmi2Status model_do_step(fmu_instance *in, double t, double h) {
    model_data *m = &in->s.m;
    double substeps = ceil(h / MAX_SUBSTEP - 1e-9);
    long i, n;
    if (!(substeps <= MAX_SUBSTEPS))
        return discard(in,
                       "fmi2DoStep: communicationStepSize = %.16g would take more than %.0f sub-steps of "
                       "%g s: step rejected, the FMU stays at t = %.16g",
                       h, MAX_SUBSTEPS, MAX_SUBSTEP, t);
    n = substeps >= 1.0 ? (long)substeps : 1;
    for (i = 0; i < n; i++) rk4_step(m, h / (double)n);
    in->s.time = t + h;
    compute_outputs(m);
    return fmi2OK;
}
