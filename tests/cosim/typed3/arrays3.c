/*
 * Arrays3: FMI 3.0 array variables beside scalars, as a Co-Simulation FMU (hptvsim test FMU; see
 * typed3_fmu.h, which gets and sets an array variable's values in row-major order).
 *
 *   u     Float64 input, array of 3 (start 1 2 3)
 *   x     Float64 input, scalar (start 0)
 *   gain  Float64 tunable parameter, scalar (start 2)
 *   y     Float64 output, array of 3:      y[j] = gain * u[j]
 *   total Float64 output, scalar:          total = u[0] + u[1] + u[2] + x
 *   grid  Float64 output, array of 2 x 3:  grid[i][j] = (i + 1) * u[j]
 *
 * The outputs are computed on every read (direct feedthrough, in Initialization Mode too);
 * fmi3DoStep only advances time.
 */
#define MODEL_NAME "Arrays3"
#define MODEL_TOKEN "{b4e81f3a-5c27-4d90-a6e2-93f0d7c1b58e}"

typedef struct {
    double u[3], x, gain, y[3], total, grid[2][3];
} model_data;

#include "typed3_fmu.h"

static const var_info *model_variables(size_t *n) {
    static const var_info vars[] = {
        {"time", 0, T_FLOAT64, K_INDEPENDENT, TIME_FIELD, NO_LIMITS},
        {"u", 1, T_FLOAT64, K_INPUT, FIELD(u), NO_LIMITS},
        {"x", 2, T_FLOAT64, K_INPUT, FIELD(x), NO_LIMITS},
        {"gain", 3, T_FLOAT64, K_TUNABLE, FIELD(gain), NO_LIMITS},
        {"y", 4, T_FLOAT64, K_OUTPUT, FIELD(y), NO_LIMITS},
        {"total", 5, T_FLOAT64, K_OUTPUT, FIELD(total), NO_LIMITS},
        {"grid", 6, T_FLOAT64, K_OUTPUT, FIELD(grid), NO_LIMITS},
    };
    *n = sizeof vars / sizeof vars[0];
    return vars;
}

static void model_start(model_data *m) {
    memset(m, 0, sizeof *m);
    m->u[0] = 1.0;
    m->u[1] = 2.0;
    m->u[2] = 3.0;
    m->gain = 2.0;
}

static void model_refresh(fmu_instance *in) {
    model_data *m = &in->s.m;
    int i, j;
    m->total = m->u[0] + m->u[1] + m->u[2] + m->x;
    for (j = 0; j < 3; j++) {
        m->y[j] = m->gain * m->u[j];
        for (i = 0; i < 2; i++) m->grid[i][j] = (i + 1) * m->u[j];
    }
}

static void model_exit_init(fmu_instance *in) { model_refresh(in); }

static fmi3Status model_do_step(fmu_instance *in, double t, double h) {
    in->s.time = t + h;
    model_refresh(in);
    return fmi3OK;
}
