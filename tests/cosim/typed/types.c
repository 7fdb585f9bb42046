/*
 * Types: every FMI 2.0 variable type (Real, Integer, Boolean, Enumeration, String) and declared
 * types with units, as an FMI 2.0 Co-Simulation FMU (hptvsim test FMU; see typed_fmu.h).
 *
 * With k the number of completed fmi2DoStep calls (0 at initialization), after
 * fmi2ExitInitializationMode and after each step (inputs are those held over the step):
 *   r_out = gain * r_in + time
 *   i_out = i_in + offset + k
 *   b_out = b_in XOR invert XOR (k odd)
 *   e_out = ((e_in - 1 + k) mod 3) + 1        (Mode: Off = 1, Slow = 2, Fast = 3)
 *   s_out = prefix + s_in + ":" + k           (e.g. "kabc:3")
 *   pos   = integral of speed_in over time    (pos += speed_in * h; 0 at initialization)
 * In initialization mode the outputs are computed on each read from the current values.
 */
#define MODEL_NAME "Types"

typedef struct {
    double r_in, speed_in, gain, r_out, pos;
    int i_in, offset, i_out, e_in, e_out, invert, b_in, b_out;
    int k;
    char s_in[128], prefix[128], s_out[300];
} model_data;

#include "typed_fmu.h"

static const char *const *model_guid_list(void) {
    static const char *const guids[] = {"{5b0f2f7e-2c1a-4d1e-9a37-6f1c0b7d9e21}", NULL};
    return guids;
}

static const var_info *model_variables(size_t *n) {
    static const var_info vars[] = {
        {"r_in", 0, T_REAL, K_INPUT, FIELD(r_in), NO_LIMITS},
        {"speed_in", 1, T_REAL, K_INPUT, FIELD(speed_in), NO_LIMITS},
        {"gain", 2, T_REAL, K_TUNABLE, FIELD(gain), NO_LIMITS},
        {"r_out", 3, T_REAL, K_OUTPUT, FIELD(r_out), NO_LIMITS},
        {"pos", 4, T_REAL, K_OUTPUT, FIELD(pos), NO_LIMITS},
        {"i_in", 10, T_INTEGER, K_INPUT, FIELD(i_in), NO_LIMITS},
        {"offset", 11, T_INTEGER, K_TUNABLE, FIELD(offset), NO_LIMITS},
        {"i_out", 12, T_INTEGER, K_OUTPUT, FIELD(i_out), NO_LIMITS},
        {"b_in", 20, T_BOOLEAN, K_INPUT, FIELD(b_in), NO_LIMITS},
        {"invert", 21, T_BOOLEAN, K_TUNABLE, FIELD(invert), NO_LIMITS},
        {"b_out", 22, T_BOOLEAN, K_OUTPUT, FIELD(b_out), NO_LIMITS},
        {"e_in", 30, T_ENUMERATION, K_INPUT, FIELD(e_in), 1.0, 3.0},
        {"e_out", 31, T_ENUMERATION, K_OUTPUT, FIELD(e_out), 1.0, 3.0},
        {"s_in", 40, T_STRING, K_INPUT, FIELD(s_in), NO_LIMITS},
        {"prefix", 41, T_STRING, K_FIXED, FIELD(prefix), NO_LIMITS},
        {"s_out", 42, T_STRING, K_OUTPUT, FIELD(s_out), NO_LIMITS},
    };
    *n = sizeof vars / sizeof vars[0];
    return vars;
}

static void model_start(model_data *m) {
    memset(m, 0, sizeof *m);
    m->gain = 2.0;
    m->offset = 10;
    m->invert = fmi2False;
    m->e_in = 1;
    strcpy(m->s_in, "abc");
    strcpy(m->prefix, "k");
}

static void outputs(model_data *m, double time) {
    m->r_out = m->gain * m->r_in + time;
    m->i_out = (fmi2Integer)((long long)m->i_in + m->offset + m->k);
    m->b_out = ((m->b_in != fmi2False) ^ (m->invert != fmi2False) ^ (m->k & 1)) ? fmi2True : fmi2False;
    m->e_out = (m->e_in - 1 + m->k) % 3 + 1;
    snprintf(m->s_out, sizeof m->s_out, "%s%s:%d", m->prefix, m->s_in, m->k);
}

static void model_refresh(fmu_instance *in) {
    if (in->s.mode == M_INIT) outputs(&in->s.m, in->s.time);
}

static void model_exit_init(fmu_instance *in) { outputs(&in->s.m, in->s.time); }

static fmi2Status model_do_step(fmu_instance *in, double t, double h) {
    model_data *m = &in->s.m;
    m->pos += m->speed_in * h;
    m->k += 1;
    in->s.time = t + h;
    outputs(m, in->s.time);
    return fmi2OK;
}
