/*
 * Terminator3: an FMI 3.0 Co-Simulation FMU that ends the simulation itself (hptvsim test FMU;
 * see typed3_fmu.h).
 *
 *   y = time (output); stop_at (tunable parameter, start 1.0).
 *
 * An fmi3DoStep whose end t + h passes stop_at by more than 1e-9 advances only to stop_at (never
 * backwards: to t when stop_at < t), logs why (category logEvents) and returns fmi3OK with
 * terminateSimulation = fmi3True and lastSuccessfulTime = the time reached (FMI 3.0: the importer
 * must then call fmi3Terminate). earlyReturn is fmi3True as well if the importer allowed early
 * returns (mightReturnEarlyFromDoStep="true"). A further fmi3DoStep returns fmi3Error. A step
 * that ends exactly at stop_at completes normally.
 */
#define MODEL_NAME "Terminator3"
#define MODEL_TOKEN "{e5b90a17-42c6-4d3f-8a5e-1f7c0d2b9e86}"

typedef struct {
    double y, stop_at;
} model_data;

#include "typed3_fmu.h"

static const var_info *model_variables(size_t *n) {
    static const var_info vars[] = {
        {"time", 0, T_FLOAT64, K_INDEPENDENT, TIME_FIELD, NO_LIMITS},
        {"y", 1, T_FLOAT64, K_OUTPUT, FIELD(y), NO_LIMITS},
        {"stop_at", 2, T_FLOAT64, K_TUNABLE, FIELD(stop_at), NO_LIMITS},
    };
    *n = sizeof vars / sizeof vars[0];
    return vars;
}

static void model_start(model_data *m) {
    memset(m, 0, sizeof *m);
    m->stop_at = 1.0;
}

static void model_refresh(fmu_instance *in) { in->s.m.y = in->s.time; }
static void model_exit_init(fmu_instance *in) { in->s.m.y = in->s.time; }

static fmi3Status model_do_step(fmu_instance *in, double t, double h) {
    double stop_at = in->s.m.stop_at;
    if (t + h > stop_at + 1e-9) {
        in->s.time = stop_at > t ? stop_at : t;
        in->s.m.y = in->s.time;
        in->s.terminate_requested = 1;
        log_event(in,
                  "fmi3DoStep: the step from t = %.16g to %.16g passes stop_at = %.16g: stopped at t = %.16g; "
                  "the FMU requests the end of the simulation (terminateSimulation = fmi3True)",
                  t, t + h, stop_at, in->s.time);
        return fmi3OK;
    }
    in->s.time = t + h;
    in->s.m.y = in->s.time;
    return fmi3OK;
}
