/*
 * InitUser: an FMI 2.0 Co-Simulation FMU with direct feedthrough that is computed on every read,
 * in initialization mode too (hptvsim test FMU; see typed_fmu.h).
 *
 *   y = a * u + b    (u input, start 0; a, b tunable parameters, start 0.5 and 1.0)
 *
 * A master that sets u in initialization mode reads y that follows it; one that sets u only
 * after fmi2ExitInitializationMode reads y of the start value at initialization. fmi2DoStep only
 * advances time.
 */
#define MODEL_NAME "InitUser"

typedef struct {
    double u, a, b, y;
} model_data;

#include "typed_fmu.h"

static const char *const *model_guid_list(void) {
    static const char *const guids[] = {"{9d62e4a1-5f3b-4c8e-a7d0-2b91c6e35f18}", NULL};
    return guids;
}

static const var_info *model_variables(size_t *n) {
    static const var_info vars[] = {
        {"u", 0, T_REAL, K_INPUT, FIELD(u), NO_LIMITS},
        {"a", 1, T_REAL, K_TUNABLE, FIELD(a), NO_LIMITS},
        {"b", 2, T_REAL, K_TUNABLE, FIELD(b), NO_LIMITS},
        {"y", 3, T_REAL, K_OUTPUT, FIELD(y), NO_LIMITS},
    };
    *n = sizeof vars / sizeof vars[0];
    return vars;
}

static void model_start(model_data *m) {
    memset(m, 0, sizeof *m);
    m->a = 0.5;
    m->b = 1.0;
}

static void model_refresh(fmu_instance *in) { in->s.m.y = in->s.m.a * in->s.m.u + in->s.m.b; }
static void model_exit_init(fmu_instance *in) { model_refresh(in); }

static fmi2Status model_do_step(fmu_instance *in, double t, double h) {
    in->s.time = t + h;
    model_refresh(in);
    return fmi2OK;
}
