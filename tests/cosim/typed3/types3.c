/*
 * Types3: every FMI 3.0 scalar type an importer meets most (Float64, Float32, Int8, UInt16, Int64,
 * Int32, Boolean, String, Enumeration), units and an enumeration type, as an FMI 3.0
 * Co-Simulation FMU (hptvsim test FMU; see typed3_fmu.h).
 *
 * With k the number of completed fmi3DoStep calls (0 at initialization), after
 * fmi3ExitInitializationMode and after each step (inputs are those held over the step):
 *   y64  = gain * x64 + time                  (Float64, unit m; x64 has unit m/s)
 *   y32  = (float)(2 * x32)                   (Float32)
 *   yi8  = i8 + k                             (Int8, wrapping modulo 2^8 as a C int8_t does)
 *   yu16 = u16 + offset + k                   (UInt16, modulo 2^16)
 *   yi64 = i64 * 2 + k                        (Int64, wrapping modulo 2^64)
 *   yb   = b XOR (k odd)                      (Boolean)
 *   ys   = s + ":" + k                        (String, e.g. "abc:3"; the FMU owns the buffer)
 *   ye   = ((e - 1 + k) mod 3) + 1            (Enumeration Mode: Off = 1, Slow = 2, Fast = 3)
 * gain (Float64) and offset (Int32) are tunable parameters. In Initialization Mode the outputs
 * are computed on each read from the current values.
 */
#define MODEL_NAME "Types3"
#define MODEL_TOKEN "{0c3e7f52-6a1d-4b8e-9f27-d45a1c8e3b60}"

#include <stdbool.h>
#include <stdint.h>

typedef struct {
    double x64, gain, y64;
    float x32, y32;
    int8_t i8, yi8;
    uint16_t u16, yu16;
    int32_t offset;
    int64_t i64, yi64, e, ye;
    bool b, yb;
    int32_t k;
    char s[128], ys[160];
} model_data;

#include "typed3_fmu.h"

static const var_info *model_variables(size_t *n) {
    static const var_info vars[] = {
        {"time", 0, T_FLOAT64, K_INDEPENDENT, TIME_FIELD, NO_LIMITS},
        {"x64", 1, T_FLOAT64, K_INPUT, FIELD(x64), NO_LIMITS},
        {"x32", 2, T_FLOAT32, K_INPUT, FIELD(x32), NO_LIMITS},
        {"i8", 3, T_INT8, K_INPUT, FIELD(i8), NO_LIMITS},
        {"u16", 4, T_UINT16, K_INPUT, FIELD(u16), NO_LIMITS},
        {"i64", 5, T_INT64, K_INPUT, FIELD(i64), NO_LIMITS},
        {"b", 6, T_BOOLEAN, K_INPUT, FIELD(b), NO_LIMITS},
        {"s", 7, T_STRING, K_INPUT, FIELD(s), NO_LIMITS},
        {"e", 8, T_ENUMERATION, K_INPUT, FIELD(e), 1.0, 3.0},
        {"gain", 9, T_FLOAT64, K_TUNABLE, FIELD(gain), NO_LIMITS},
        {"offset", 10, T_INT32, K_TUNABLE, FIELD(offset), NO_LIMITS},
        {"y64", 11, T_FLOAT64, K_OUTPUT, FIELD(y64), NO_LIMITS},
        {"y32", 12, T_FLOAT32, K_OUTPUT, FIELD(y32), NO_LIMITS},
        {"yi8", 13, T_INT8, K_OUTPUT, FIELD(yi8), NO_LIMITS},
        {"yu16", 14, T_UINT16, K_OUTPUT, FIELD(yu16), NO_LIMITS},
        {"yi64", 15, T_INT64, K_OUTPUT, FIELD(yi64), NO_LIMITS},
        {"yb", 16, T_BOOLEAN, K_OUTPUT, FIELD(yb), NO_LIMITS},
        {"ys", 17, T_STRING, K_OUTPUT, FIELD(ys), NO_LIMITS},
        {"ye", 18, T_ENUMERATION, K_OUTPUT, FIELD(ye), 1.0, 3.0},
    };
    *n = sizeof vars / sizeof vars[0];
    return vars;
}

static void model_start(model_data *m) {
    memset(m, 0, sizeof *m);
    m->gain = 2.0;
    m->offset = 10;
    m->e = 1;
    strcpy(m->s, "abc");
}

/* v modulo 2^8 as an int8_t, without implementation-defined conversions */
static int8_t wrap_int8(int64_t v) {
    uint8_t u = (uint8_t)v;
    return u <= 127 ? (int8_t)u : (int8_t)((int)u - 256);
}

/* u modulo 2^64 as an int64_t, without implementation-defined conversions */
static int64_t wrap_int64(uint64_t u) { return u <= (uint64_t)INT64_MAX ? (int64_t)u : -(int64_t)(UINT64_MAX - u) - 1; }

static void outputs(fmu_snapshot *s) {
    model_data *m = &s->m;
    m->y64 = m->gain * m->x64 + s->time;
    m->y32 = 2.0f * m->x32;
    m->yi8 = wrap_int8((int64_t)m->i8 + m->k);
    m->yu16 = (uint16_t)((int64_t)m->u16 + m->offset + m->k);
    m->yi64 = wrap_int64((uint64_t)m->i64 * 2u + (uint64_t)m->k);
    m->yb = m->b != (m->k % 2 == 1);
    m->ye = (m->e - 1 + m->k) % 3 + 1;
    snprintf(m->ys, sizeof m->ys, "%s:%d", m->s, (int)m->k);
}

static void model_refresh(fmu_instance *in) {
    if (in->s.mode == M_INIT) outputs(&in->s);
}

static void model_exit_init(fmu_instance *in) { outputs(&in->s); }

static fmi3Status model_do_step(fmu_instance *in, double t, double h) {
    in->s.m.k += 1;
    in->s.time = t + h;
    outputs(&in->s);
    return fmi3OK;
}
