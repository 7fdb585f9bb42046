/*
 * Terminator: an FMI 2.0 Co-Simulation FMU that ends the simulation itself (hptvsim test FMU;
 * see typed_fmu.h).
 *
 *   y = time (output); stop_at (tunable parameter, start 1.0).
 *
 * A fmi2DoStep whose end t + h passes stop_at by more than 1e-9 advances only to stop_at (never
 * backwards: to t when stop_at < t), logs why and returns fmi2Discard: then
 * fmi2GetBooleanStatus(fmi2Terminated) is fmi2True and fmi2GetRealStatus(fmi2LastSuccessfulTime)
 * is the time reached, and the instance is in StepFailed, where a further fmi2DoStep is an
 * illegal call (fmi2Error).
 */
#define MODEL_NAME "Terminator"

typedef struct {
    double y, stop_at;
} model_data;

#include "typed_fmu.h"

static const char *const *model_guid_list(void) {
    static const char *const guids[] = {"{a4d3c9b2-7e61-4f08-b5a9-3c2e1d0f8b74}", NULL};
    return guids;
}

static const var_info *model_variables(size_t *n) {
    static const var_info vars[] = {
        {"y", 0, T_REAL, K_OUTPUT, FIELD(y), NO_LIMITS},
        {"stop_at", 1, T_REAL, K_TUNABLE, FIELD(stop_at), NO_LIMITS},
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

static fmi2Status model_do_step(fmu_instance *in, double t, double h) {
    double stop_at = in->s.m.stop_at;
    if (t + h > stop_at + 1e-9) {
        in->s.time = stop_at > t ? stop_at : t;
        in->s.m.y = in->s.time;
        in->s.terminated = 1;
        return discard(in,
                       "fmi2DoStep: the step from t = %.16g to %.16g passes stop_at = %.16g: stopped at "
                       "t = %.16g; the FMU requests the end of the simulation (fmi2Terminated = fmi2True)",
                       t, t + h, stop_at, in->s.time);
    }
    in->s.time = t + h;
    in->s.m.y = in->s.time;
    return fmi2OK;
}
