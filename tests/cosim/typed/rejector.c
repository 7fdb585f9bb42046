/*
 * Rejector (and RejectorFixed, the same binary code under another model identifier and GUID):
 * an FMI 2.0 Co-Simulation FMU that rejects steps longer than max_step (hptvsim test FMU; see
 * typed_fmu.h).
 *
 *   u (input, start 1.0), max_step (tunable parameter, start 0.1),
 *   y (output, 0 at initialization; y += u * h per accepted step),
 *   accepted (Integer output: the number of accepted fmi2DoStep calls).
 *
 * A fmi2DoStep with h > max_step + 1e-12 logs why and returns fmi2Discard without advancing:
 * fmi2GetBooleanStatus(fmi2Terminated) is fmi2False and fmi2GetRealStatus(fmi2LastSuccessfulTime)
 * is the unchanged time t. The instance is then in StepFailed (FMI 2.0.4): to redo the step with
 * a shorter step size the master restores the FMU state taken before it (fmi2SetFMUstate), as
 * the standard says; a fmi2DoStep straight from StepFailed is an illegal call (fmi2Error).
 */
#define MODEL_NAME "Rejector"

typedef struct {
    double u, max_step, y;
    int accepted;
} model_data;

#include "typed_fmu.h"

static const char *const *model_guid_list(void) {
    static const char *const guids[] = {
        "{3e7a5c10-9b24-4d6f-8e13-c0a2b4f69d57}", /* Rejector.fmu */
        "{c81f6b2d-0a4e-4b79-92d5-7e3f1a8c6b40}", /* RejectorFixed.fmu */
        NULL,
    };
    return guids;
}

static const var_info *model_variables(size_t *n) {
    static const var_info vars[] = {
        {"u", 0, T_REAL, K_INPUT, FIELD(u), NO_LIMITS},
        {"max_step", 1, T_REAL, K_TUNABLE, FIELD(max_step), 0.0, HUGE_VAL},
        {"y", 2, T_REAL, K_OUTPUT, FIELD(y), NO_LIMITS},
        {"accepted", 3, T_INTEGER, K_OUTPUT, FIELD(accepted), NO_LIMITS},
    };
    *n = sizeof vars / sizeof vars[0];
    return vars;
}

static void model_start(model_data *m) {
    memset(m, 0, sizeof *m);
    m->u = 1.0;
    m->max_step = 0.1;
}

static void model_refresh(fmu_instance *in) { (void)in; }
static void model_exit_init(fmu_instance *in) { (void)in; }

static fmi2Status model_do_step(fmu_instance *in, double t, double h) {
    model_data *m = &in->s.m;
    if (h > m->max_step + 1e-12)
        return discard(in,
                       "fmi2DoStep: communicationStepSize = %.16g exceeds max_step = %.16g: step rejected, "
                       "the FMU stays at t = %.16g (fmi2Terminated = fmi2False); restore the FMU state and "
                       "redo the step with h <= max_step",
                       h, m->max_step, t);
    m->y += m->u * h;
    m->accepted += 1;
    in->s.time = t + h;
    return fmi2OK;
}
