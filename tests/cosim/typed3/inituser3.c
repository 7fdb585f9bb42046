/*
 * InitUser3: an FMI 3.0 Co-Simulation FMU with direct feedthrough that is computed on every read,
 * in Initialization Mode too (hptvsim test FMU; see typed3_fmu.h).
 *
 *   y = a * u + b    (u input, start 0; a, b tunable parameters, start 0.5 and 1.0)
 *
 * An importer that sets u in Initialization Mode reads y that follows it; one that sets u only
 * after fmi3ExitInitializationMode reads y of the start value at initialization. fmi3DoStep only
 * advances time.
 */
#define MODEL_NAME "InitUser3"
#define MODEL_TOKEN "{7a41d2c8-3e95-4f06-b1d7-8c2e5f9a0b34}"

typedef struct {
    double u, a, b, y;
} model_data;

#include "typed3_fmu.h"

static const var_info *model_variables(size_t *n) {
    static const var_info vars[] = {
        {"time", 0, T_FLOAT64, K_INDEPENDENT, TIME_FIELD, NO_LIMITS},
        {"u", 1, T_FLOAT64, K_INPUT, FIELD(u), NO_LIMITS},
        {"a", 2, T_FLOAT64, K_TUNABLE, FIELD(a), NO_LIMITS},
        {"b", 3, T_FLOAT64, K_TUNABLE, FIELD(b), NO_LIMITS},
        {"y", 4, T_FLOAT64, K_OUTPUT, FIELD(y), NO_LIMITS},
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

static fmi3Status model_do_step(fmu_instance *in, double t, double h) {
    in->s.time = t + h;
    model_refresh(in);
    return fmi3OK;
}
