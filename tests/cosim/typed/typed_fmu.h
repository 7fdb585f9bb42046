/*
 * typed_fmu.h: the FMI 2.0 Co-Simulation interface shared by hptvsim's hand-written test FMUs
 * (Types, Terminator, Rejector/RejectorFixed, InitUser, Once; see tests/cosim/typed_fmus.py).
 *
 * A model file defines, before it includes this header:
 *   MODEL_NAME                the model's name, for log messages;
 *   MODEL_MAX_INSTANCES       (optional) how many instances may live at a time in this process;
 *   model_data                a plain struct with every variable and internal state (no pointers:
 *                             an FMU state is a struct copy and serializes as raw bytes);
 * and, after it, the hooks declared below (model_guid_list, model_variables, model_start,
 * model_refresh, model_exit_init, model_do_step).
 *
 * State machine (FMI 2.0.4, section 4.2.4):
 *   fmi2Instantiate -> Instantiated -> fmi2EnterInitializationMode -> InitializationMode
 *   -> fmi2ExitInitializationMode -> StepComplete -> fmi2Terminate -> Terminated.
 *   fmi2DoStep is allowed in StepComplete only. fmi2Discard from fmi2DoStep leads to StepFailed:
 *   from there the master may read variables and the status, call fmi2Terminate, fmi2Reset, or
 *   restore an earlier FMU state with fmi2SetFMUstate (which restores the state machine's state
 *   too, so a state taken before the step leads back to StepComplete) and then redo the step.
 *   Any function that returns fmi2Error logs why and leaves the instance in the Error state
 *   (FMI 2.0.4, section 2.1.3): only fmi2GetXXX (for debugging), fmi2Get/SetFMUstate, fmi2Reset
 *   and fmi2FreeInstance are possible then.
 *   fmi2GetXXX is allowed from InitializationMode on (not in Instantiated); fmi2SetXXX for inputs
 *   and tunable parameters in Instantiated, InitializationMode and StepComplete, for fixed
 *   parameters in Instantiated and InitializationMode only; outputs cannot be set.
 *   fmi2Reset returns any state to Instantiated with the start values.
 *
 * Error and discard messages are always passed to the logger (categories logStatusError and
 * logStatusDiscard); fmi2SetDebugLogging only checks the category names.
 */
#ifndef TYPED_FMU_H
#define TYPED_FMU_H

#include <math.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdio.h>
#include <string.h>

#include "fmi2Functions.h"

/* ---- what a model provides ---------------------------------------------------------------- */

typedef enum { T_REAL, T_INTEGER, T_BOOLEAN, T_ENUMERATION, T_STRING } var_type;
typedef enum { K_INPUT, K_TUNABLE, K_FIXED, K_OUTPUT } var_kind;

/* One scalar variable: where it lives in model_data, who may set it, and its legal range. */
typedef struct {
    const char *name;
    fmi2ValueReference vr;
    var_type type;
    var_kind kind;
    size_t offset; /* into model_data */
    size_t size;   /* of the field: the capacity of a String buffer */
    double min, max;
} var_info;

#define FIELD(f) offsetof(model_data, f), sizeof(((model_data *)0)->f)
#define NO_LIMITS (-HUGE_VAL), HUGE_VAL

/* The state machine's states, as bits for the masks of the allowed calls. */
#define M_INSTANTIATED 1
#define M_INIT 2
#define M_STEP_COMPLETE 4
#define M_STEP_FAILED 8
#define M_TERMINATED 16
#define M_ERROR 32
#define M_ANY (M_INSTANTIATED | M_INIT | M_STEP_COMPLETE | M_STEP_FAILED | M_TERMINATED | M_ERROR)
#define M_GET (M_INIT | M_STEP_COMPLETE | M_STEP_FAILED | M_TERMINATED | M_ERROR)
#define M_SET (M_INSTANTIATED | M_INIT | M_STEP_COMPLETE)
#define M_STATUS (M_STEP_COMPLETE | M_STEP_FAILED | M_TERMINATED)

/* Everything an FMU state holds: the state machine's state, time, status flags, the model. */
typedef struct {
    int mode;
    double time;
    int stop_defined;
    double stop_time;
    int terminated; /* fmi2Terminated: the FMU asked the master to end the simulation */
    model_data m;
} fmu_snapshot;

typedef struct {
    fmi2CallbackFunctions cb;
    char name[128];
    int logging_on;
    fmu_snapshot s;
} fmu_instance;

/* An FMU state handed to the master (fmi2GetFMUstate) and its serialized form. */
#define STATE_MAGIC 0x48505456u /* "HPTV" */
typedef struct {
    unsigned magic;
    char model[32]; /* MODEL_NAME: another model's state is rejected */
    fmu_snapshot s;
} fmu_state_box;

static int is_our_state(const fmu_state_box *box) {
    return box && box->magic == STATE_MAGIC && strncmp(box->model, MODEL_NAME, sizeof box->model) == 0;
}

static const char *const *model_guid_list(void);     /* NULL-terminated: the GUIDs accepted */
static const var_info *model_variables(size_t *n);  /* every variable, and their number */
static void model_start(model_data *m);      /* the start values */
static void model_refresh(fmu_instance *in); /* before each fmi2GetXXX: values computed on read */
static void model_exit_init(fmu_instance *in);
/* One step from t to t + h: sets in->s.time; fmi2Discard must be logged (with discard()). */
static fmi2Status model_do_step(fmu_instance *in, double t, double h);

/* ---- logging ------------------------------------------------------------------------------ */

static void vlog_msg(fmu_instance *in, fmi2Status st, const char *cat, const char *fmt, va_list ap) {
    char msg[512];
    vsnprintf(msg, sizeof msg, fmt, ap);
    if (in && in->cb.logger) in->cb.logger(in->cb.componentEnvironment, in->name, st, cat, "%s", msg);
}

/* Log an error, enter the Error state, return fmi2Error. */
static fmi2Status fail(fmu_instance *in, const char *fmt, ...) {
    va_list ap;
    va_start(ap, fmt);
    vlog_msg(in, fmi2Error, "logStatusError", fmt, ap);
    va_end(ap);
    in->s.mode = M_ERROR;
    return fmi2Error;
}

/* Log why a step was discarded, return fmi2Discard (fmi2DoStep then enters StepFailed). */
static fmi2Status discard(fmu_instance *in, const char *fmt, ...) {
    va_list ap;
    va_start(ap, fmt);
    vlog_msg(in, fmi2Discard, "logStatusDiscard", fmt, ap);
    va_end(ap);
    return fmi2Discard;
}

static const char *mode_name(int mode) {
    switch (mode) {
        case M_INSTANTIATED: return "Instantiated";
        case M_INIT: return "InitializationMode";
        case M_STEP_COMPLETE: return "StepComplete";
        case M_STEP_FAILED: return "StepFailed";
        case M_TERMINATED: return "Terminated";
        default: return "Error";
    }
}

/* The call-sequence check every instance function starts with. */
#define CHECK_STATE(fn, mask)                                                                    \
    do {                                                                                         \
        if (!in) return fmi2Error;                                                               \
        if (!(in->s.mode & (mask)))                                                              \
            return fail(in, "%s: illegal call sequence: not allowed in state %s", fn,            \
                        mode_name(in->s.mode));                                                  \
    } while (0)

/* ---- creation, destruction, state machine -------------------------------------------------- */

#ifdef MODEL_MAX_INSTANCES
static int live_instances = 0; /* instances alive in this process (this loaded binary) */
#endif

static void reset_instance(fmu_instance *in) {
    memset(&in->s, 0, sizeof in->s);
    in->s.mode = M_INSTANTIATED;
    model_start(&in->s.m);
}

FMI2_Export const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
FMI2_Export const char *fmi2GetVersion(void) { return fmi2Version; }

FMI2_Export fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid, fmi2String location,
                                          const fmi2CallbackFunctions *f, fmi2Boolean visible,
                                          fmi2Boolean logging_on) {
    fmu_instance tmp, *in;
    size_t i;
    int guid_ok = 0;
    (void)location;
    (void)visible;
    if (!f || !f->allocateMemory || !f->freeMemory) return NULL; /* nobody to tell: no logger */
    memset(&tmp, 0, sizeof tmp);
    tmp.cb = *f;
    snprintf(tmp.name, sizeof tmp.name, "%s", name ? name : MODEL_NAME);
    if (!name || !name[0]) {
        fail(&tmp, "fmi2Instantiate: instanceName must be a non-empty string");
        return NULL;
    }
    if (type != fmi2CoSimulation) {
        fail(&tmp, "fmi2Instantiate: %s is a Co-Simulation FMU only (fmuType = %d)", MODEL_NAME, (int)type);
        return NULL;
    }
    const char *const *guids = model_guid_list();
    for (i = 0; guid && guids[i]; i++) guid_ok |= strcmp(guid, guids[i]) == 0;
    if (!guid_ok) {
        fail(&tmp, "fmi2Instantiate: GUID %s does not match this binary of %s", guid ? guid : "(null)", MODEL_NAME);
        return NULL;
    }
#ifdef MODEL_MAX_INSTANCES
    if (live_instances >= MODEL_MAX_INSTANCES) {
        fail(&tmp,
             "fmi2Instantiate: %s can be instantiated only once per process "
             "(canBeInstantiatedOnlyOncePerProcess=\"true\") and %d instance(s) still live; "
             "free it first",
             MODEL_NAME, live_instances);
        return NULL;
    }
#endif
    in = (fmu_instance *)f->allocateMemory(1, sizeof *in);
    if (!in) {
        fail(&tmp, "fmi2Instantiate: out of memory");
        return NULL;
    }
    memset(in, 0, sizeof *in);
    in->cb = *f;
    memcpy(in->name, tmp.name, sizeof in->name);
    in->logging_on = logging_on != fmi2False;
    reset_instance(in);
#ifdef MODEL_MAX_INSTANCES
    live_instances++;
#endif
    return in;
}

FMI2_Export void fmi2FreeInstance(fmi2Component c) {
    fmu_instance *in = (fmu_instance *)c;
    if (!in) return;
#ifdef MODEL_MAX_INSTANCES
    live_instances--;
#endif
    in->cb.freeMemory(in);
}

FMI2_Export fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n, const fmi2String cat[]) {
    fmu_instance *in = (fmu_instance *)c;
    size_t i;
    CHECK_STATE("fmi2SetDebugLogging", M_ANY);
    for (i = 0; i < n; i++) {
        if (!cat || !cat[i] || (strcmp(cat[i], "logStatusError") != 0 && strcmp(cat[i], "logStatusDiscard") != 0))
            return fail(in, "fmi2SetDebugLogging: unknown log category %s", cat && cat[i] ? cat[i] : "(null)");
    }
    in->logging_on = on != fmi2False;
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean tol_defined, fmi2Real tol, fmi2Real start,
                                           fmi2Boolean stop_defined, fmi2Real stop) {
    fmu_instance *in = (fmu_instance *)c;
    (void)tol_defined;
    (void)tol;
    CHECK_STATE("fmi2SetupExperiment", M_INSTANTIATED);
    if (stop_defined && stop < start)
        return fail(in, "fmi2SetupExperiment: stopTime = %g is before startTime = %g", stop, start);
    in->s.time = start;
    in->s.stop_defined = stop_defined != fmi2False;
    in->s.stop_time = stop;
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    fmu_instance *in = (fmu_instance *)c;
    CHECK_STATE("fmi2EnterInitializationMode", M_INSTANTIATED);
    in->s.mode = M_INIT;
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    fmu_instance *in = (fmu_instance *)c;
    CHECK_STATE("fmi2ExitInitializationMode", M_INIT);
    model_exit_init(in);
    in->s.mode = M_STEP_COMPLETE;
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2Terminate(fmi2Component c) {
    fmu_instance *in = (fmu_instance *)c;
    CHECK_STATE("fmi2Terminate", M_STEP_COMPLETE | M_STEP_FAILED);
    in->s.mode = M_TERMINATED;
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2Reset(fmi2Component c) {
    fmu_instance *in = (fmu_instance *)c;
    CHECK_STATE("fmi2Reset", M_ANY);
    reset_instance(in);
    return fmi2OK;
}

/* ---- getting and setting variables --------------------------------------------------------- */

static const var_info *find_var(fmi2ValueReference vr, var_type t1, var_type t2) {
    size_t i, n;
    const var_info *vars = model_variables(&n);
    for (i = 0; i < n; i++)
        if (vars[i].vr == vr && (vars[i].type == t1 || vars[i].type == t2)) return &vars[i];
    return NULL;
}

static void *field_of(fmu_instance *in, const var_info *v) { return (char *)&in->s.m + v->offset; }

/* May variable v be set now? (FMI 2.0.4, table of section 4.2.4, footnotes 1, 3 and 6) */
static fmi2Status check_settable(fmu_instance *in, const char *fn, const var_info *v) {
    int mask = 0;
    switch (v->kind) {
        case K_INPUT:
        case K_TUNABLE: mask = M_INSTANTIATED | M_INIT | M_STEP_COMPLETE; break;
        case K_FIXED: mask = M_INSTANTIATED | M_INIT; break;
        case K_OUTPUT: return fail(in, "%s: %s is an output and cannot be set", fn, v->name);
    }
    if (!(in->s.mode & mask))
        return fail(in, "%s: %s cannot be set in state %s", fn, v->name, mode_name(in->s.mode));
    return fmi2OK;
}

#define GET_PROLOGUE(fn)                                                                         \
    fmu_instance *in = (fmu_instance *)c;                                                        \
    size_t i;                                                                                    \
    CHECK_STATE(fn, M_GET);                                                                      \
    if (n > 0 && (!vr || !value)) return fail(in, "%s: NULL argument", fn);                      \
    model_refresh(in)

#define SET_PROLOGUE(fn)                                                                         \
    fmu_instance *in = (fmu_instance *)c;                                                        \
    size_t i;                                                                                    \
    CHECK_STATE(fn, M_SET);                                                                      \
    if (n > 0 && (!vr || !value)) return fail(in, "%s: NULL argument", fn)

FMI2_Export fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real value[]) {
    GET_PROLOGUE("fmi2GetReal");
    for (i = 0; i < n; i++) {
        const var_info *v = find_var(vr[i], T_REAL, T_REAL);
        if (!v) return fail(in, "fmi2GetReal: no Real variable has value reference %u", (unsigned)vr[i]);
        value[i] = *(const fmi2Real *)field_of(in, v);
    }
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                      fmi2Integer value[]) {
    GET_PROLOGUE("fmi2GetInteger");
    for (i = 0; i < n; i++) {
        const var_info *v = find_var(vr[i], T_INTEGER, T_ENUMERATION);
        if (!v)
            return fail(in, "fmi2GetInteger: no Integer or Enumeration variable has value reference %u",
                        (unsigned)vr[i]);
        value[i] = *(const fmi2Integer *)field_of(in, v);
    }
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                      fmi2Boolean value[]) {
    GET_PROLOGUE("fmi2GetBoolean");
    for (i = 0; i < n; i++) {
        const var_info *v = find_var(vr[i], T_BOOLEAN, T_BOOLEAN);
        if (!v) return fail(in, "fmi2GetBoolean: no Boolean variable has value reference %u", (unsigned)vr[i]);
        value[i] = *(const fmi2Boolean *)field_of(in, v);
    }
    return fmi2OK;
}

/* The strings returned point into the instance (the FMU owns them): valid until the next call. */
FMI2_Export fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2String value[]) {
    GET_PROLOGUE("fmi2GetString");
    for (i = 0; i < n; i++) {
        const var_info *v = find_var(vr[i], T_STRING, T_STRING);
        if (!v) return fail(in, "fmi2GetString: no String variable has value reference %u", (unsigned)vr[i]);
        value[i] = (const char *)field_of(in, v);
    }
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                   const fmi2Real value[]) {
    SET_PROLOGUE("fmi2SetReal");
    for (i = 0; i < n; i++) {
        const var_info *v = find_var(vr[i], T_REAL, T_REAL);
        if (!v) return fail(in, "fmi2SetReal: no Real variable has value reference %u", (unsigned)vr[i]);
        if (check_settable(in, "fmi2SetReal", v) != fmi2OK) return fmi2Error;
        if (!(value[i] >= v->min && value[i] <= v->max)) /* also rejects NaN */
            return fail(in, "fmi2SetReal: %s = %g is outside [%g, %g]", v->name, value[i], v->min, v->max);
        *(fmi2Real *)field_of(in, v) = value[i];
    }
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                      const fmi2Integer value[]) {
    SET_PROLOGUE("fmi2SetInteger");
    for (i = 0; i < n; i++) {
        const var_info *v = find_var(vr[i], T_INTEGER, T_ENUMERATION);
        if (!v)
            return fail(in, "fmi2SetInteger: no Integer or Enumeration variable has value reference %u",
                        (unsigned)vr[i]);
        if (check_settable(in, "fmi2SetInteger", v) != fmi2OK) return fmi2Error;
        if (!((double)value[i] >= v->min && (double)value[i] <= v->max))
            return fail(in, "fmi2SetInteger: %s = %d is outside [%g, %g]", v->name, (int)value[i], v->min, v->max);
        *(fmi2Integer *)field_of(in, v) = value[i];
    }
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                      const fmi2Boolean value[]) {
    SET_PROLOGUE("fmi2SetBoolean");
    for (i = 0; i < n; i++) {
        const var_info *v = find_var(vr[i], T_BOOLEAN, T_BOOLEAN);
        if (!v) return fail(in, "fmi2SetBoolean: no Boolean variable has value reference %u", (unsigned)vr[i]);
        if (check_settable(in, "fmi2SetBoolean", v) != fmi2OK) return fmi2Error;
        *(fmi2Boolean *)field_of(in, v) = value[i] ? fmi2True : fmi2False;
    }
    return fmi2OK;
}

/* The FMU copies the strings into its own buffers (the caller's may go away after the call). */
FMI2_Export fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                     const fmi2String value[]) {
    SET_PROLOGUE("fmi2SetString");
    for (i = 0; i < n; i++) {
        const var_info *v = find_var(vr[i], T_STRING, T_STRING);
        if (!v) return fail(in, "fmi2SetString: no String variable has value reference %u", (unsigned)vr[i]);
        if (check_settable(in, "fmi2SetString", v) != fmi2OK) return fmi2Error;
        if (!value[i]) return fail(in, "fmi2SetString: %s: NULL string", v->name);
        if (strlen(value[i]) >= v->size)
            return fail(in, "fmi2SetString: %s: the string is longer than %u bytes", v->name,
                        (unsigned)(v->size - 1));
        memcpy(field_of(in, v), value[i], strlen(value[i]) + 1);
    }
    return fmi2OK;
}

/* ---- FMU states: a struct copy ------------------------------------------------------------- */

FMI2_Export fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *state) {
    fmu_instance *in = (fmu_instance *)c;
    fmu_state_box *box;
    CHECK_STATE("fmi2GetFMUstate", M_ANY);
    if (!state) return fail(in, "fmi2GetFMUstate: NULL argument");
    box = (fmu_state_box *)*state; /* not NULL: a state of ours to overwrite */
    if (box && !is_our_state(box)) return fail(in, "fmi2GetFMUstate: *FMUstate is not an FMU state of this FMU");
    if (!box) box = (fmu_state_box *)in->cb.allocateMemory(1, sizeof *box);
    if (!box) return fail(in, "fmi2GetFMUstate: out of memory");
    box->magic = STATE_MAGIC;
    snprintf(box->model, sizeof box->model, "%s", MODEL_NAME);
    box->s = in->s;
    *state = box;
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate state) {
    fmu_instance *in = (fmu_instance *)c;
    const fmu_state_box *box = (const fmu_state_box *)state;
    CHECK_STATE("fmi2SetFMUstate", M_ANY);
    if (!is_our_state(box)) return fail(in, "fmi2SetFMUstate: not an FMU state of this FMU");
    in->s = box->s;
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *state) {
    fmu_instance *in = (fmu_instance *)c;
    CHECK_STATE("fmi2FreeFMUstate", M_ANY);
    if (!state) return fail(in, "fmi2FreeFMUstate: NULL argument");
    if (*state) {
        ((fmu_state_box *)*state)->magic = 0;
        in->cb.freeMemory(*state);
    }
    *state = NULL;
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate state, size_t *size) {
    fmu_instance *in = (fmu_instance *)c;
    CHECK_STATE("fmi2SerializedFMUstateSize", M_ANY);
    if (!state || !size) return fail(in, "fmi2SerializedFMUstateSize: NULL argument");
    *size = sizeof(fmu_state_box);
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate state, fmi2Byte out[], size_t size) {
    fmu_instance *in = (fmu_instance *)c;
    const fmu_state_box *box = (const fmu_state_box *)state;
    CHECK_STATE("fmi2SerializeFMUstate", M_ANY);
    if (!box || !out) return fail(in, "fmi2SerializeFMUstate: NULL argument");
    if (!is_our_state(box)) return fail(in, "fmi2SerializeFMUstate: not an FMU state of this FMU");
    if (size != sizeof *box)
        return fail(in, "fmi2SerializeFMUstate: size = %u, expected %u", (unsigned)size, (unsigned)sizeof *box);
    memcpy(out, box, sizeof *box);
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte in_bytes[], size_t size,
                                               fmi2FMUstate *state) {
    fmu_instance *in = (fmu_instance *)c;
    fmu_state_box box;
    CHECK_STATE("fmi2DeSerializeFMUstate", M_ANY);
    if (!in_bytes || !state) return fail(in, "fmi2DeSerializeFMUstate: NULL argument");
    if (size != sizeof box)
        return fail(in, "fmi2DeSerializeFMUstate: size = %u, expected %u (another FMU's state?)", (unsigned)size,
                    (unsigned)sizeof box);
    memcpy(&box, in_bytes, sizeof box);
    if (!is_our_state(&box)) return fail(in, "fmi2DeSerializeFMUstate: not a state of this FMU");
    if (!*state) *state = in->cb.allocateMemory(1, sizeof box);
    if (!*state) return fail(in, "fmi2DeSerializeFMUstate: out of memory");
    memcpy(*state, &box, sizeof box);
    return fmi2OK;
}

/* ---- not provided (capability flags false) -------------------------------------------------- */

FMI2_Export fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference u[], size_t nu,
                                                    const fmi2ValueReference k[], size_t nk, const fmi2Real dk[],
                                                    fmi2Real du[]) {
    fmu_instance *in = (fmu_instance *)c;
    (void)u; (void)nu; (void)k; (void)nk; (void)dk; (void)du;
    if (!in) return fmi2Error;
    return fail(in, "fmi2GetDirectionalDerivative: not provided (providesDirectionalDerivative=\"false\")");
}

FMI2_Export fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                                   const fmi2Integer order[], const fmi2Real value[]) {
    fmu_instance *in = (fmu_instance *)c;
    (void)vr; (void)n; (void)order; (void)value;
    if (!in) return fmi2Error;
    return fail(in, "fmi2SetRealInputDerivatives: not provided (canInterpolateInputs=\"false\")");
}

FMI2_Export fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                                    const fmi2Integer order[], fmi2Real value[]) {
    fmu_instance *in = (fmu_instance *)c;
    (void)vr; (void)n; (void)order; (void)value;
    if (!in) return fmi2Error;
    return fail(in, "fmi2GetRealOutputDerivatives: not provided (maxOutputDerivativeOrder=\"0\")");
}

FMI2_Export fmi2Status fmi2CancelStep(fmi2Component c) {
    fmu_instance *in = (fmu_instance *)c;
    if (!in) return fmi2Error;
    return fail(in, "fmi2CancelStep: not provided (canRunAsynchronuously=\"false\": fmi2DoStep never returns fmi2Pending)");
}

/* ---- stepping and its status ----------------------------------------------------------------- */

static double time_tolerance(double t) { return 1e-9 * (fabs(t) > 1.0 ? fabs(t) : 1.0); }

FMI2_Export fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean no_set_prior) {
    fmu_instance *in = (fmu_instance *)c;
    fmi2Status status;
    (void)no_set_prior;
    if (in && in->s.mode == M_STEP_FAILED && in->s.terminated)
        return fail(in, "fmi2DoStep: illegal call sequence: the FMU ended the simulation at t = %.16g "
                    "(fmi2Terminated = fmi2True); call fmi2Terminate", in->s.time);
    if (in && in->s.mode == M_STEP_FAILED)
        return fail(in, "fmi2DoStep: illegal call sequence: the previous step was discarded (StepFailed); "
                    "restore an FMU state with fmi2SetFMUstate before the next fmi2DoStep");
    CHECK_STATE("fmi2DoStep", M_STEP_COMPLETE);
    if (!(h > 0.0)) return fail(in, "fmi2DoStep: communicationStepSize = %g must be > 0", h);
    if (fabs(t - in->s.time) > time_tolerance(in->s.time))
        return fail(in, "fmi2DoStep: currentCommunicationPoint = %.16g but the FMU is at t = %.16g", t, in->s.time);
    if (in->s.stop_defined && t + h > in->s.stop_time + time_tolerance(in->s.stop_time))
        return fail(in, "fmi2DoStep: the step to t = %.16g passes stopTime = %.16g (fmi2SetupExperiment)", t + h,
                    in->s.stop_time);
    status = model_do_step(in, t, h);
    if (status == fmi2Discard) in->s.mode = M_STEP_FAILED;
    return status;
}

static fmi2Status status_unavailable(fmu_instance *in, const char *fn, int kind) {
    return discard(in, "%s: status kind %d is not available (only fmi2LastSuccessfulTime from fmi2GetRealStatus "
                   "and fmi2Terminated from fmi2GetBooleanStatus; fmi2DoStep never returns fmi2Pending)", fn, kind);
}

FMI2_Export fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value) {
    fmu_instance *in = (fmu_instance *)c;
    (void)value;
    CHECK_STATE("fmi2GetStatus", M_STATUS);
    return status_unavailable(in, "fmi2GetStatus", (int)s);
}

FMI2_Export fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value) {
    fmu_instance *in = (fmu_instance *)c;
    CHECK_STATE("fmi2GetRealStatus", M_STATUS);
    if (!value) return fail(in, "fmi2GetRealStatus: NULL argument");
    if (s != fmi2LastSuccessfulTime) return status_unavailable(in, "fmi2GetRealStatus", (int)s);
    *value = in->s.time;
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value) {
    fmu_instance *in = (fmu_instance *)c;
    (void)value;
    CHECK_STATE("fmi2GetIntegerStatus", M_STATUS);
    return status_unavailable(in, "fmi2GetIntegerStatus", (int)s);
}

FMI2_Export fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value) {
    fmu_instance *in = (fmu_instance *)c;
    CHECK_STATE("fmi2GetBooleanStatus", M_STATUS);
    if (!value) return fail(in, "fmi2GetBooleanStatus: NULL argument");
    if (s != fmi2Terminated) return status_unavailable(in, "fmi2GetBooleanStatus", (int)s);
    *value = in->s.terminated ? fmi2True : fmi2False;
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value) {
    fmu_instance *in = (fmu_instance *)c;
    (void)value;
    CHECK_STATE("fmi2GetStringStatus", M_STATUS);
    return status_unavailable(in, "fmi2GetStringStatus", (int)s);
}

#endif /* TYPED_FMU_H */
