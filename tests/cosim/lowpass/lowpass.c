/*
 * LowPass: a first-order low-pass filter as an FMI 2.0 Co-Simulation FMU, written by hand for
 * hptvsim's co-simulation tests (a system that is not the vehicle model).
 *
 *   T dy/dt = K u - y,   y(0) = y_0
 *
 * fmi2DoStep solves it exactly for an input held over the step:
 *   y(t + h) = K u + (y(t) - K u) exp(-h / T).
 *
 * fail_time >= 0 makes the step that would pass it return fmi2Error (with a logged message):
 * the tests use it to check how a master handles a component that fails mid-run.
 */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "fmi2Functions.h"

#define GUID "{8c4e1a52-3f0b-4a7e-9d61-2b5c7e9f0a13}"
#define VR_U 0
#define VR_Y 1
#define VR_T 2
#define VR_Y0 3
#define VR_FAIL 4
#define VR_K 5
#define N_VR 6

typedef struct {
    double time, u, y, T, y0, fail_time, K;
    int mode; /* 0 instantiated, 1 initialisation, 2 stepping, 3 error */
} lp_state;

typedef struct {
    fmi2CallbackFunctions cb;
    char name[64];
    lp_state s;
} lp_instance;

static void lp_defaults(lp_state *s) {
    memset(s, 0, sizeof *s);
    s->T = 1.0;
    s->K = 1.0;
    s->fail_time = -1.0;
}

static fmi2Status lp_error(lp_instance *inst, const char *msg) {
    if (inst && inst->cb.logger)
        inst->cb.logger(inst->cb.componentEnvironment, inst->name, fmi2Error, "logStatusError", "%s", msg);
    return fmi2Error;
}

FMI2_Export const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
FMI2_Export const char *fmi2GetVersion(void) { return fmi2Version; }

FMI2_Export fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n, const fmi2String cat[]) {
    (void)c; (void)on; (void)n; (void)cat;
    return fmi2OK;
}

FMI2_Export fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid, fmi2String loc,
                                          const fmi2CallbackFunctions *f, fmi2Boolean visible,
                                          fmi2Boolean logging) {
    lp_instance *inst;
    (void)loc; (void)visible; (void)logging;
    if (!f || !f->allocateMemory || type != fmi2CoSimulation || !guid || strcmp(guid, GUID) != 0) return NULL;
    inst = (lp_instance *)f->allocateMemory(1, sizeof *inst);
    if (!inst) return NULL;
    inst->cb = *f;
    snprintf(inst->name, sizeof inst->name, "%s", name ? name : "LowPass");
    lp_defaults(&inst->s);
    return inst;
}

FMI2_Export void fmi2FreeInstance(fmi2Component c) {
    lp_instance *inst = (lp_instance *)c;
    if (inst) inst->cb.freeMemory(inst);
}

FMI2_Export fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean tolDef, fmi2Real tol, fmi2Real start,
                                           fmi2Boolean stopDef, fmi2Real stop) {
    lp_instance *inst = (lp_instance *)c;
    (void)tolDef; (void)tol; (void)stopDef; (void)stop;
    inst->s.time = start;
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    ((lp_instance *)c)->s.mode = 1;
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    lp_instance *inst = (lp_instance *)c;
    inst->s.y = inst->s.y0;
    inst->s.mode = 2;
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2Terminate(fmi2Component c) { (void)c; return fmi2OK; }

FMI2_Export fmi2Status fmi2Reset(fmi2Component c) {
    lp_defaults(&((lp_instance *)c)->s);
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real v[]) {
    lp_instance *inst = (lp_instance *)c;
    size_t i;
    for (i = 0; i < n; i++) {
        switch (vr[i]) {
            case VR_U: v[i] = inst->s.u; break;
            case VR_Y: v[i] = inst->s.y; break;
            case VR_T: v[i] = inst->s.T; break;
            case VR_Y0: v[i] = inst->s.y0; break;
            case VR_FAIL: v[i] = inst->s.fail_time; break;
            case VR_K: v[i] = inst->s.K; break;
            default: return lp_error(inst, "fmi2GetReal: unknown value reference");
        }
    }
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Real v[]) {
    lp_instance *inst = (lp_instance *)c;
    size_t i;
    for (i = 0; i < n; i++) {
        if (!isfinite(v[i])) return lp_error(inst, "fmi2SetReal: value is not finite");
        switch (vr[i]) {
            case VR_U: inst->s.u = v[i]; break;
            case VR_T:
                if (!(v[i] > 0.0)) return lp_error(inst, "fmi2SetReal: T must be > 0");
                inst->s.T = v[i];
                break;
            case VR_Y0: inst->s.y0 = v[i]; break;
            case VR_FAIL: inst->s.fail_time = v[i]; break;
            case VR_K: inst->s.K = v[i]; break;
            default: return lp_error(inst, "fmi2SetReal: unknown or read-only value reference");
        }
    }
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Integer v[]) {
    (void)vr; (void)v;
    return n ? lp_error((lp_instance *)c, "no Integer variables") : fmi2OK;
}
FMI2_Export fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                      const fmi2Integer v[]) {
    (void)vr; (void)v;
    return n ? lp_error((lp_instance *)c, "no Integer variables") : fmi2OK;
}
FMI2_Export fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Boolean v[]) {
    (void)vr; (void)v;
    return n ? lp_error((lp_instance *)c, "no Boolean variables") : fmi2OK;
}
FMI2_Export fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                      const fmi2Boolean v[]) {
    (void)vr; (void)v;
    return n ? lp_error((lp_instance *)c, "no Boolean variables") : fmi2OK;
}
FMI2_Export fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2String v[]) {
    (void)vr; (void)v;
    return n ? lp_error((lp_instance *)c, "no String variables") : fmi2OK;
}
FMI2_Export fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                     const fmi2String v[]) {
    (void)vr; (void)v;
    return n ? lp_error((lp_instance *)c, "no String variables") : fmi2OK;
}

FMI2_Export fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *state) {
    lp_instance *inst = (lp_instance *)c;
    lp_state *s = (lp_state *)*state;
    if (!s) s = (lp_state *)inst->cb.allocateMemory(1, sizeof *s);
    if (!s) return lp_error(inst, "out of memory");
    *s = inst->s;
    *state = s;
    return fmi2OK;
}
FMI2_Export fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate state) {
    if (!state) return lp_error((lp_instance *)c, "fmi2SetFMUstate: NULL state");
    ((lp_instance *)c)->s = *(lp_state *)state;
    return fmi2OK;
}
FMI2_Export fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *state) {
    lp_instance *inst = (lp_instance *)c;
    if (state && *state) inst->cb.freeMemory(*state);
    if (state) *state = NULL;
    return fmi2OK;
}
FMI2_Export fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate state, size_t *size) {
    (void)c; (void)state;
    *size = sizeof(lp_state);
    return fmi2OK;
}
FMI2_Export fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate state, fmi2Byte out[], size_t size) {
    if (size < sizeof(lp_state)) return lp_error((lp_instance *)c, "buffer too small");
    memcpy(out, state, sizeof(lp_state));
    return fmi2OK;
}
FMI2_Export fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte in[], size_t size,
                                               fmi2FMUstate *state) {
    lp_instance *inst = (lp_instance *)c;
    if (size != sizeof(lp_state)) return lp_error(inst, "wrong size");
    if (!*state) *state = inst->cb.allocateMemory(1, sizeof(lp_state));
    memcpy(*state, in, sizeof(lp_state));
    return fmi2OK;
}
FMI2_Export fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference u[], size_t nu,
                                                    const fmi2ValueReference k[], size_t nk,
                                                    const fmi2Real dk[], fmi2Real du[]) {
    (void)u; (void)nu; (void)k; (void)nk; (void)dk; (void)du;
    return lp_error((lp_instance *)c, "not provided");
}

FMI2_Export fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                                   const fmi2Integer o[], const fmi2Real v[]) {
    (void)vr; (void)n; (void)o; (void)v;
    return lp_error((lp_instance *)c, "not provided");
}
FMI2_Export fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                                    const fmi2Integer o[], fmi2Real v[]) {
    (void)vr; (void)n; (void)o; (void)v;
    return lp_error((lp_instance *)c, "not provided");
}

FMI2_Export fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean noSetPrior) {
    lp_instance *inst = (lp_instance *)c;
    double a, target;
    char msg[160];
    (void)noSetPrior;
    if (inst->s.mode == 3) return lp_error(inst, "fmi2DoStep: the instance failed earlier; reset it");
    if (inst->s.mode != 2) return lp_error(inst, "fmi2DoStep: not initialised");
    if (inst->s.fail_time >= 0.0 && t + h > inst->s.fail_time) {
        inst->s.mode = 3;
        snprintf(msg, sizeof msg, "fmi2DoStep: fail_time = %g reached in the step from t = %g", inst->s.fail_time, t);
        return lp_error(inst, msg);
    }
    a = exp(-h / inst->s.T);
    target = inst->s.K * inst->s.u;
    inst->s.y = target + (inst->s.y - target) * a;
    inst->s.time = t + h;
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2CancelStep(fmi2Component c) { return lp_error((lp_instance *)c, "not provided"); }
FMI2_Export fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *v) {
    (void)s; (void)v;
    return lp_error((lp_instance *)c, "not provided");
}
FMI2_Export fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *v) {
    (void)s;
    *v = ((lp_instance *)c)->s.time;
    return fmi2OK;
}
FMI2_Export fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *v) {
    (void)s; (void)v;
    return lp_error((lp_instance *)c, "not provided");
}
FMI2_Export fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *v) {
    (void)s;
    *v = fmi2False;
    return fmi2OK;
}
FMI2_Export fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *v) {
    (void)s; (void)v;
    return lp_error((lp_instance *)c, "not provided");
}
