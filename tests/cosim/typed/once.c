/*
 * Once: an FMI 2.0 Co-Simulation FMU with canBeInstantiatedOnlyOncePerProcess="true" (hptvsim
 * test FMU; see typed_fmu.h). A static counter makes fmi2Instantiate return NULL (and log why)
 * while another instance of this loaded binary lives; fmi2FreeInstance releases the slot.
 *
 *   y = time (output)
 */
#define MODEL_NAME "Once"
#define MODEL_MAX_INSTANCES 1

typedef struct {
    double y;
} model_data;

#include "typed_fmu.h"

static const char *const *model_guid_list(void) {
    static const char *const guids[] = {"{6f18b3d5-c2a7-4e90-8b4f-d15e7a0c2963}", NULL};
    return guids;
}

static const var_info *model_variables(size_t *n) {
    static const var_info vars[] = {
        {"y", 0, T_REAL, K_OUTPUT, FIELD(y), NO_LIMITS},
    };
    *n = sizeof vars / sizeof vars[0];
    return vars;
}

static void model_start(model_data *m) { memset(m, 0, sizeof *m); }
static void model_refresh(fmu_instance *in) { in->s.m.y = in->s.time; }
static void model_exit_init(fmu_instance *in) { in->s.m.y = in->s.time; }

static fmi2Status model_do_step(fmu_instance *in, double t, double h) {
    in->s.time = t + h;
    in->s.m.y = in->s.time;
    return fmi2OK;
}
