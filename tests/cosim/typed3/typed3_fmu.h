/*
 * typed3_fmu.h: the FMI 3.0 Co-Simulation interface shared by hptvsim's hand-written FMI 3 test
 * FMUs (Types3, InitUser3, Terminator3, Arrays3; see tests/cosim/typed3_fmus.py), built against
 * the FMI 3.0 headers shipped with FMPy (fmi3Functions.h, fmi3FunctionTypes.h,
 * fmi3PlatformTypes.h).
 *
 * A model file defines, before it includes this header:
 *   MODEL_NAME    the model's name (its modelIdentifier), for log messages and FMU states;
 *   MODEL_TOKEN   the instantiationToken of its modelDescription.xml;
 *   model_data    a plain struct with every variable and internal state (no pointers: an FMU
 *                 state is a struct copy and serializes as raw bytes);
 * and, after it, the hooks declared below (model_variables, model_start, model_refresh,
 * model_exit_init, model_do_step).
 *
 * A numeric variable (Float, Int, UInt, Boolean, Enumeration) is a scalar or, when its field in
 * model_data is a C array, an array variable of that many values in row-major order (FMI 3.0,
 * section 2.2.9); Strings and Binaries are scalars. Values are get and set with the FMI 3.0 array
 * convention (nValueReferences value references, nValues values): nValues must equal the number
 * of scalar values the value references refer to (nValueReferences for scalars). Enumerations
 * are accessed with fmi3GetInt64 / fmi3SetInt64 and stored as int64_t; the independent variable
 * (time) can be read as Float64.
 *
 * State machine (FMI 3.0, Co-Simulation without Event Mode, clocks or intermediate update):
 *   fmi3InstantiateCoSimulation -> Instantiated -> fmi3EnterInitializationMode
 *   -> Initialization Mode -> fmi3ExitInitializationMode -> Step Mode -> fmi3Terminate
 *   -> Terminated. fmi3DoStep is allowed in Step Mode only and returns its output arguments
 *   eventHandlingNeeded (always fmi3False), terminateSimulation, earlyReturn and
 *   lastSuccessfulTime. After a step that returned terminateSimulation = fmi3True the importer
 *   must call fmi3Terminate: a further fmi3DoStep is an error. earlyReturn is fmi3True only if
 *   the importer allowed it (earlyReturnAllowed) and the FMU stopped before the end of the step.
 *   fmi3Get{VariableType} is allowed from Initialization Mode on (not in Instantiated);
 *   fmi3Set{VariableType} for inputs and tunable parameters in Instantiated, Initialization Mode
 *   and Step Mode; outputs and the independent variable cannot be set.
 *   Any function that returns fmi3Error logs why (if logging is on) and leaves the instance in
 *   the Error state, from which only fmi3Get{VariableType} (for debugging), the FMU state
 *   functions, fmi3Reset, fmi3SetDebugLogging and fmi3FreeInstance are possible; fmi3SetFMUState
 *   also restores the state machine's state. fmi3Reset returns any state to Instantiated with
 *   the start values.
 *
 * Logging (FMI 3.0): with loggingOn = fmi3False the FMU never calls logMessage. With
 * loggingOn = fmi3True every category is on; fmi3SetDebugLogging switches all categories
 * (nCategories = 0) or the listed ones. Categories: logStatusError (why a call returned
 * fmi3Error) and logEvents (the FMU's requests to end the simulation).
 *
 * Not provided (each returns fmi3Error with a logged reason): Model Exchange and Scheduled
 * Execution (their instantiate functions return NULL), Event Mode, clocks, configuration mode,
 * directional and adjoint derivatives, output derivatives, per-element dependencies.
 */
#ifndef TYPED3_FMU_H
#define TYPED3_FMU_H

#include <math.h>
#include <stdarg.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi3Functions.h"

/* ---- what a model provides ---------------------------------------------------------------- */

typedef enum {
    T_FLOAT32, T_FLOAT64, T_INT8, T_UINT8, T_INT16, T_UINT16, T_INT32, T_UINT32, T_INT64, T_UINT64,
    T_BOOLEAN, T_STRING, T_BINARY, T_ENUMERATION
} var_type;
typedef enum { K_INDEPENDENT, K_INPUT, K_TUNABLE, K_OUTPUT } var_kind;

/* One variable (a scalar or an array, see above): where it lives in the FMU state, who may set
 * it, and the legal range of its values. */
typedef struct {
    const char *name;
    fmi3ValueReference vr;
    var_type type;
    var_kind kind;
    size_t offset; /* into fmu_snapshot */
    size_t size;   /* of the field: the capacity of a String buffer, the bytes of an array */
    double min, max;
} var_info;

/* The state machine's states, as bits for the masks of the allowed calls. */
#define M_INSTANTIATED 1
#define M_INIT 2
#define M_STEP 4
#define M_TERMINATED 8
#define M_ERROR 16
#define M_ANY (M_INSTANTIATED | M_INIT | M_STEP | M_TERMINATED | M_ERROR)
#define M_GET (M_INIT | M_STEP | M_TERMINATED | M_ERROR)
#define M_SET (M_INSTANTIATED | M_INIT | M_STEP)

/* Everything an FMU state holds: the state machine's state, time, flags, the model. */
typedef struct {
    int mode;
    double time;
    int stop_defined;
    double stop_time;
    int terminate_requested; /* a step returned terminateSimulation = fmi3True */
    model_data m;
} fmu_snapshot;

#define FIELD(f) offsetof(fmu_snapshot, m.f), sizeof(((model_data *)0)->f)
#define TIME_FIELD offsetof(fmu_snapshot, time), sizeof(double)
#define NO_LIMITS (-HUGE_VAL), HUGE_VAL

/* Log categories, as bits. */
#define LOG_ERROR 1
#define LOG_EVENTS 2
#define LOG_ALL (LOG_ERROR | LOG_EVENTS)

typedef struct {
    fmi3InstanceEnvironment env;
    fmi3LogMessageCallback log_message;
    char name[128];
    int log_mask; /* the categories logged; 0: logging off */
    int early_return_allowed;
    fmu_snapshot s;
} fmu_instance;

/* An FMU state handed to the importer (fmi3GetFMUState) and its serialized form. */
#define STATE_MAGIC 0x48505433u /* "HPT3" */
typedef struct {
    unsigned magic;
    char model[32]; /* MODEL_NAME: another model's state is rejected */
    fmu_snapshot s;
} fmu_state_box;

static int is_our_state(const fmu_state_box *box) {
    return box && box->magic == STATE_MAGIC && strncmp(box->model, MODEL_NAME, sizeof box->model) == 0;
}

static const var_info *model_variables(size_t *n); /* every variable, and their number */
static void model_start(model_data *m);            /* the start values */
static void model_refresh(fmu_instance *in);       /* before each fmi3Get: values computed on read */
static void model_exit_init(fmu_instance *in);
/* One step from t to t + h: sets in->s.time (at most t + h) and in->s.terminate_requested. */
static fmi3Status model_do_step(fmu_instance *in, double t, double h);

/* ---- logging ------------------------------------------------------------------------------ */

static void vlog_msg(fmu_instance *in, fmi3Status st, int category, const char *fmt, va_list ap) {
    char msg[512];
    if (!in || !in->log_message || !(in->log_mask & category)) return;
    vsnprintf(msg, sizeof msg, fmt, ap);
    in->log_message(in->env, st, category == LOG_ERROR ? "logStatusError" : "logEvents", msg);
}

/* Log an error, enter the Error state, return fmi3Error. */
static fmi3Status fail(fmu_instance *in, const char *fmt, ...) {
    va_list ap;
    va_start(ap, fmt);
    vlog_msg(in, fmi3Error, LOG_ERROR, fmt, ap);
    va_end(ap);
    in->s.mode = M_ERROR;
    return fmi3Error;
}

#ifdef __GNUC__
#define MAYBE_UNUSED __attribute__((unused))
#else
#define MAYBE_UNUSED
#endif

/* Log an event of the model (status fmi3OK, category logEvents); not every model logs events. */
MAYBE_UNUSED static void log_event(fmu_instance *in, const char *fmt, ...) {
    va_list ap;
    va_start(ap, fmt);
    vlog_msg(in, fmi3OK, LOG_EVENTS, fmt, ap);
    va_end(ap);
}

static const char *mode_name(int mode) {
    switch (mode) {
        case M_INSTANTIATED: return "Instantiated";
        case M_INIT: return "Initialization Mode";
        case M_STEP: return "Step Mode";
        case M_TERMINATED: return "Terminated";
        default: return "Error";
    }
}

/* The call-sequence check every instance function starts with. */
#define CHECK_STATE(fn, mask)                                                                    \
    do {                                                                                         \
        if (!in) return fmi3Error;                                                               \
        if (!(in->s.mode & (mask)))                                                              \
            return fail(in, "%s: illegal call sequence: not allowed in state %s", fn,            \
                        mode_name(in->s.mode));                                                  \
    } while (0)

/* A function this FMU does not provide: fmi3Error, with the reason logged. */
static fmi3Status unsupported(fmi3Instance instance, const char *fn, const char *why) {
    fmu_instance *in = (fmu_instance *)instance;
    if (!in) return fmi3Error;
    return fail(in, "%s: not supported: %s", fn, why);
}

#define NO_EVENT_MODE "the FMU has no Event Mode (hasEventMode=\"false\"; instantiate it with eventModeUsed = fmi3False)"
#define NO_CLOCKS "the FMU has no clocks"
#define ME_ONLY "a Model Exchange function; " MODEL_NAME " is a Co-Simulation FMU"
#define NO_STRUCTURAL "the FMU has no structural parameters (no Configuration or Reconfiguration Mode)"

/* ---- creation, destruction, state machine -------------------------------------------------- */

static void reset_instance(fmu_instance *in) {
    memset(&in->s, 0, sizeof in->s);
    in->s.mode = M_INSTANTIATED;
    model_start(&in->s.m);
}

FMI3_Export const char *fmi3GetVersion(void) { return fmi3Version; }

/* Log why an instantiate function returns NULL (if logging is on). */
static void instantiate_failed(fmi3InstanceEnvironment env, fmi3LogMessageCallback log_message, fmi3Boolean logging_on,
                               const char *fmt, ...) {
    fmu_instance tmp;
    va_list ap;
    memset(&tmp, 0, sizeof tmp);
    tmp.env = env;
    tmp.log_message = log_message;
    tmp.log_mask = logging_on ? LOG_ALL : 0;
    va_start(ap, fmt);
    vlog_msg(&tmp, fmi3Error, LOG_ERROR, fmt, ap);
    va_end(ap);
}

FMI3_Export fmi3Instance fmi3InstantiateCoSimulation(fmi3String name, fmi3String token, fmi3String resource_path,
                                                     fmi3Boolean visible, fmi3Boolean logging_on,
                                                     fmi3Boolean event_mode_used, fmi3Boolean early_return_allowed,
                                                     const fmi3ValueReference required_intermediate[],
                                                     size_t n_required_intermediate, fmi3InstanceEnvironment env,
                                                     fmi3LogMessageCallback log_message,
                                                     fmi3IntermediateUpdateCallback intermediate_update) {
    fmu_instance *in;
    (void)resource_path;
    (void)visible;
    (void)required_intermediate;
    (void)intermediate_update;
    if (!name || !name[0]) {
        instantiate_failed(env, log_message, logging_on,
                           "fmi3InstantiateCoSimulation: instanceName must be a non-empty string");
        return NULL;
    }
    if (!token || strcmp(token, MODEL_TOKEN) != 0) {
        instantiate_failed(env, log_message, logging_on,
                           "fmi3InstantiateCoSimulation: instantiationToken %s does not match this binary of %s",
                           token ? token : "(null)", MODEL_NAME);
        return NULL;
    }
    if (event_mode_used) {
        instantiate_failed(env, log_message, logging_on, "fmi3InstantiateCoSimulation: eventModeUsed = fmi3True "
                           "but %s has no Event Mode (hasEventMode=\"false\")", MODEL_NAME);
        return NULL;
    }
    if (n_required_intermediate > 0) {
        instantiate_failed(env, log_message, logging_on, "fmi3InstantiateCoSimulation: %u required intermediate "
                           "variable(s) but %s provides no intermediate update (providesIntermediateUpdate=\"false\")",
                           (unsigned)n_required_intermediate, MODEL_NAME);
        return NULL;
    }
    in = (fmu_instance *)calloc(1, sizeof *in);
    if (!in) {
        instantiate_failed(env, log_message, logging_on, "fmi3InstantiateCoSimulation: out of memory");
        return NULL;
    }
    in->env = env;
    in->log_message = log_message;
    snprintf(in->name, sizeof in->name, "%s", name);
    in->log_mask = logging_on ? LOG_ALL : 0;
    in->early_return_allowed = early_return_allowed != fmi3False;
    reset_instance(in);
    return in;
}

FMI3_Export fmi3Instance fmi3InstantiateModelExchange(fmi3String name, fmi3String token, fmi3String resource_path,
                                                      fmi3Boolean visible, fmi3Boolean logging_on,
                                                      fmi3InstanceEnvironment env,
                                                      fmi3LogMessageCallback log_message) {
    (void)name;
    (void)token;
    (void)resource_path;
    (void)visible;
    instantiate_failed(env, log_message, logging_on,
                       "fmi3InstantiateModelExchange: not supported: %s is a Co-Simulation FMU only", MODEL_NAME);
    return NULL;
}

FMI3_Export fmi3Instance fmi3InstantiateScheduledExecution(fmi3String name, fmi3String token,
                                                           fmi3String resource_path, fmi3Boolean visible,
                                                           fmi3Boolean logging_on, fmi3InstanceEnvironment env,
                                                           fmi3LogMessageCallback log_message,
                                                           fmi3ClockUpdateCallback clock_update,
                                                           fmi3LockPreemptionCallback lock_preemption,
                                                           fmi3UnlockPreemptionCallback unlock_preemption) {
    (void)name;
    (void)token;
    (void)resource_path;
    (void)visible;
    (void)clock_update;
    (void)lock_preemption;
    (void)unlock_preemption;
    instantiate_failed(env, log_message, logging_on,
                       "fmi3InstantiateScheduledExecution: not supported: %s is a Co-Simulation FMU only", MODEL_NAME);
    return NULL;
}

FMI3_Export void fmi3FreeInstance(fmi3Instance instance) { free(instance); }

FMI3_Export fmi3Status fmi3SetDebugLogging(fmi3Instance instance, fmi3Boolean on, size_t n, const fmi3String cat[]) {
    fmu_instance *in = (fmu_instance *)instance;
    int mask = 0;
    size_t i;
    CHECK_STATE("fmi3SetDebugLogging", M_ANY);
    if (n == 0) mask = LOG_ALL;
    for (i = 0; i < n; i++) {
        if (cat && cat[i] && strcmp(cat[i], "logStatusError") == 0)
            mask |= LOG_ERROR;
        else if (cat && cat[i] && strcmp(cat[i], "logEvents") == 0)
            mask |= LOG_EVENTS;
        else
            return fail(in, "fmi3SetDebugLogging: unknown log category %s", cat && cat[i] ? cat[i] : "(null)");
    }
    in->log_mask = on ? (in->log_mask | mask) : (in->log_mask & ~mask);
    return fmi3OK;
}

FMI3_Export fmi3Status fmi3EnterInitializationMode(fmi3Instance instance, fmi3Boolean tol_defined, fmi3Float64 tol,
                                                   fmi3Float64 start, fmi3Boolean stop_defined, fmi3Float64 stop) {
    fmu_instance *in = (fmu_instance *)instance;
    (void)tol_defined;
    (void)tol;
    CHECK_STATE("fmi3EnterInitializationMode", M_INSTANTIATED);
    if (stop_defined && stop < start)
        return fail(in, "fmi3EnterInitializationMode: stopTime = %g is before startTime = %g", stop, start);
    in->s.time = start;
    in->s.stop_defined = stop_defined != fmi3False;
    in->s.stop_time = stop;
    in->s.mode = M_INIT;
    return fmi3OK;
}

FMI3_Export fmi3Status fmi3ExitInitializationMode(fmi3Instance instance) {
    fmu_instance *in = (fmu_instance *)instance;
    CHECK_STATE("fmi3ExitInitializationMode", M_INIT);
    model_exit_init(in);
    in->s.mode = M_STEP; /* eventModeUsed is always fmi3False: straight to Step Mode */
    return fmi3OK;
}

FMI3_Export fmi3Status fmi3Terminate(fmi3Instance instance) {
    fmu_instance *in = (fmu_instance *)instance;
    CHECK_STATE("fmi3Terminate", M_STEP);
    in->s.mode = M_TERMINATED;
    return fmi3OK;
}

FMI3_Export fmi3Status fmi3Reset(fmi3Instance instance) {
    fmu_instance *in = (fmu_instance *)instance;
    CHECK_STATE("fmi3Reset", M_ANY);
    reset_instance(in);
    return fmi3OK;
}

/* ---- getting and setting variables --------------------------------------------------------- */

static const char *type_name(var_type t) {
    static const char *const names[] = {"Float32", "Float64", "Int8",    "UInt8",  "Int16",  "UInt16", "Int32",
                                        "UInt32",  "Int64",   "UInt64",  "Boolean", "String", "Binary", "Enumeration"};
    return names[t];
}

/* The variable of value reference vr accessed with the functions of type t (Int64: Enumeration too). */
static const var_info *find_var(fmi3ValueReference vr, var_type t) {
    size_t i, n;
    const var_info *vars = model_variables(&n);
    for (i = 0; i < n; i++)
        if (vars[i].vr == vr && (vars[i].type == t || (t == T_INT64 && vars[i].type == T_ENUMERATION)))
            return &vars[i];
    return NULL;
}

static void *field_of(fmu_instance *in, const var_info *v) { return (char *)&in->s + v->offset; }

/* May variable v be set now? (FMI 3.0, section 2.3: inputs and tunable parameters) */
static fmi3Status check_settable(fmu_instance *in, const char *fn, const var_info *v) {
    switch (v->kind) {
        case K_INDEPENDENT: return fail(in, "%s: %s is the independent variable and cannot be set", fn, v->name);
        case K_OUTPUT: return fail(in, "%s: %s is an output and cannot be set", fn, v->name);
        default: break;
    }
    if (!(in->s.mode & M_SET))
        return fail(in, "%s: %s cannot be set in state %s", fn, v->name, mode_name(in->s.mode));
    return fmi3OK;
}

/* The number of scalar values of variable v: 1 for a scalar, the number of elements of an array
 * (its field's size over the size of one value); Strings and Binaries are scalars. */
static size_t values_of(const var_info *v) {
    static const size_t value_size[] = {sizeof(fmi3Float32), sizeof(fmi3Float64), sizeof(fmi3Int8),
                                        sizeof(fmi3UInt8),   sizeof(fmi3Int16),   sizeof(fmi3UInt16),
                                        sizeof(fmi3Int32),   sizeof(fmi3UInt32),  sizeof(fmi3Int64),
                                        sizeof(fmi3UInt64),  sizeof(fmi3Boolean), 0 /* String */,
                                        0 /* Binary */,      sizeof(int64_t) /* Enumeration */};
    return value_size[v->type] ? v->size / value_size[v->type] : 1;
}

/* The checks every fmi3Get and fmi3Set of type t starts with: state, arguments, nValues (the
 * number of scalar values the value references refer to; an unknown one counts as one and is
 * reported by the caller). */
static fmi3Status check_access(fmu_instance *in, const char *fn, const fmi3ValueReference vr[], size_t nvr,
                               const void *values, size_t n_values, var_type t) {
    size_t i, total = 0;
    if (nvr > 0 && (!vr || !values)) return fail(in, "%s: NULL argument", fn);
    for (i = 0; i < nvr; i++) {
        const var_info *v = find_var(vr[i], t);
        total += v ? values_of(v) : 1;
    }
    if (n_values != total)
        return fail(in, "%s: nValues = %u but the %u value reference(s) refer to %u scalar value(s)", fn,
                    (unsigned)n_values, (unsigned)nvr, (unsigned)total);
    return fmi3OK;
}

static fmi3Status no_such_variable(fmu_instance *in, const char *fn, var_type t, fmi3ValueReference vr) {
    return fail(in, "%s: no %s%s variable has value reference %u", fn, type_name(t),
                t == T_INT64 ? " or Enumeration" : "", (unsigned)vr);
}

#define GETTER(Name, T)                                                                                           \
    FMI3_Export fmi3Status fmi3Get##Name(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,        \
                                         fmi3##Name values[], size_t n_values) {                                  \
        fmu_instance *in = (fmu_instance *)instance;                                                              \
        size_t i, j = 0; /* j: index of the variable's first value in values[] */                                \
        CHECK_STATE("fmi3Get" #Name, M_GET);                                                                      \
        if (check_access(in, "fmi3Get" #Name, vr, nvr, values, n_values, T) != fmi3OK) return fmi3Error;         \
        model_refresh(in);                                                                                        \
        for (i = 0; i < nvr; i++) {                                                                               \
            const var_info *v = find_var(vr[i], T);                                                               \
            if (!v) return no_such_variable(in, "fmi3Get" #Name, T, vr[i]);                                      \
            memcpy(&values[j], field_of(in, v), values_of(v) * sizeof values[0]);                                 \
            j += values_of(v);                                                                                    \
        }                                                                                                         \
        return fmi3OK;                                                                                            \
    }

/* Values outside [min, max] (and NaN) are rejected. */
#define SETTER(Name, T)                                                                                           \
    FMI3_Export fmi3Status fmi3Set##Name(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,        \
                                         const fmi3##Name values[], size_t n_values) {                            \
        fmu_instance *in = (fmu_instance *)instance;                                                              \
        size_t i, j = 0; /* j: index of the variable's first value in values[] */                                \
        CHECK_STATE("fmi3Set" #Name, M_SET);                                                                      \
        if (check_access(in, "fmi3Set" #Name, vr, nvr, values, n_values, T) != fmi3OK) return fmi3Error;         \
        for (i = 0; i < nvr; i++) {                                                                               \
            const var_info *v = find_var(vr[i], T);                                                               \
            size_t e;                                                                                             \
            if (!v) return no_such_variable(in, "fmi3Set" #Name, T, vr[i]);                                      \
            if (check_settable(in, "fmi3Set" #Name, v) != fmi3OK) return fmi3Error;                               \
            for (e = 0; e < values_of(v); e++) {                                                                  \
                double x = (double)values[j + e];                                                                 \
                if (!(x >= v->min && x <= v->max))                                                                \
                    return fail(in, "fmi3Set" #Name ": %s = %g is outside [%g, %g]", v->name, x, v->min, v->max); \
            }                                                                                                     \
            memcpy(field_of(in, v), &values[j], values_of(v) * sizeof values[0]);                                 \
            j += values_of(v);                                                                                    \
        }                                                                                                         \
        return fmi3OK;                                                                                            \
    }

GETTER(Float32, T_FLOAT32)
GETTER(Float64, T_FLOAT64)
GETTER(Int8, T_INT8)
GETTER(UInt8, T_UINT8)
GETTER(Int16, T_INT16)
GETTER(UInt16, T_UINT16)
GETTER(Int32, T_INT32)
GETTER(UInt32, T_UINT32)
GETTER(Int64, T_INT64)
GETTER(UInt64, T_UINT64)
GETTER(Boolean, T_BOOLEAN)

SETTER(Float32, T_FLOAT32)
SETTER(Float64, T_FLOAT64)
SETTER(Int8, T_INT8)
SETTER(UInt8, T_UINT8)
SETTER(Int16, T_INT16)
SETTER(UInt16, T_UINT16)
SETTER(Int32, T_INT32)
SETTER(UInt32, T_UINT32)
SETTER(Int64, T_INT64)
SETTER(UInt64, T_UINT64)
SETTER(Boolean, T_BOOLEAN)

/* The strings returned point into the instance (the FMU owns them): valid until the next call. */
FMI3_Export fmi3Status fmi3GetString(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                     fmi3String values[], size_t n_values) {
    fmu_instance *in = (fmu_instance *)instance;
    size_t i;
    CHECK_STATE("fmi3GetString", M_GET);
    if (check_access(in, "fmi3GetString", vr, nvr, values, n_values, T_STRING) != fmi3OK) return fmi3Error;
    model_refresh(in);
    for (i = 0; i < nvr; i++) {
        const var_info *v = find_var(vr[i], T_STRING);
        if (!v) return no_such_variable(in, "fmi3GetString", T_STRING, vr[i]);
        values[i] = (const char *)field_of(in, v);
    }
    return fmi3OK;
}

/* The FMU copies the strings into its own buffers (the caller's may go away after the call). */
FMI3_Export fmi3Status fmi3SetString(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                     const fmi3String values[], size_t n_values) {
    fmu_instance *in = (fmu_instance *)instance;
    size_t i;
    CHECK_STATE("fmi3SetString", M_SET);
    if (check_access(in, "fmi3SetString", vr, nvr, values, n_values, T_STRING) != fmi3OK) return fmi3Error;
    for (i = 0; i < nvr; i++) {
        const var_info *v = find_var(vr[i], T_STRING);
        if (!v) return no_such_variable(in, "fmi3SetString", T_STRING, vr[i]);
        if (check_settable(in, "fmi3SetString", v) != fmi3OK) return fmi3Error;
        if (!values[i]) return fail(in, "fmi3SetString: %s: NULL string", v->name);
        if (strlen(values[i]) >= v->size)
            return fail(in, "fmi3SetString: %s: the string is longer than %u bytes", v->name, (unsigned)(v->size - 1));
        memcpy(field_of(in, v), values[i], strlen(values[i]) + 1);
    }
    return fmi3OK;
}

/* No model has Binary variables: any value reference is unknown. */
FMI3_Export fmi3Status fmi3GetBinary(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                     size_t value_sizes[], fmi3Binary values[], size_t n_values) {
    fmu_instance *in = (fmu_instance *)instance;
    CHECK_STATE("fmi3GetBinary", M_GET);
    if (nvr > 0 && !value_sizes) return fail(in, "fmi3GetBinary: NULL argument");
    if (check_access(in, "fmi3GetBinary", vr, nvr, values, n_values, T_BINARY) != fmi3OK) return fmi3Error;
    if (nvr > 0) return no_such_variable(in, "fmi3GetBinary", T_BINARY, vr[0]);
    return fmi3OK;
}

FMI3_Export fmi3Status fmi3SetBinary(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                     const size_t value_sizes[], const fmi3Binary values[], size_t n_values) {
    fmu_instance *in = (fmu_instance *)instance;
    CHECK_STATE("fmi3SetBinary", M_SET);
    if (nvr > 0 && !value_sizes) return fail(in, "fmi3SetBinary: NULL argument");
    if (check_access(in, "fmi3SetBinary", vr, nvr, values, n_values, T_BINARY) != fmi3OK) return fmi3Error;
    if (nvr > 0) return no_such_variable(in, "fmi3SetBinary", T_BINARY, vr[0]);
    return fmi3OK;
}

FMI3_Export fmi3Status fmi3GetClock(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                    fmi3Clock values[]) {
    (void)vr; (void)nvr; (void)values;
    return unsupported(instance, "fmi3GetClock", NO_CLOCKS);
}

FMI3_Export fmi3Status fmi3SetClock(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                    const fmi3Clock values[]) {
    (void)vr; (void)nvr; (void)values;
    return unsupported(instance, "fmi3SetClock", NO_CLOCKS);
}

/* ---- variable dependencies, derivatives: not provided ----------------------------------------- */

FMI3_Export fmi3Status fmi3GetNumberOfVariableDependencies(fmi3Instance instance, fmi3ValueReference vr,
                                                           size_t *n) {
    (void)vr; (void)n;
    return unsupported(instance, "fmi3GetNumberOfVariableDependencies", "providesPerElementDependencies=\"false\"");
}

FMI3_Export fmi3Status fmi3GetVariableDependencies(fmi3Instance instance, fmi3ValueReference dependent,
                                                   size_t element_of_dependent[], fmi3ValueReference independents[],
                                                   size_t element_of_independents[], fmi3DependencyKind kinds[],
                                                   size_t n) {
    (void)dependent; (void)element_of_dependent; (void)independents; (void)element_of_independents; (void)kinds;
    (void)n;
    return unsupported(instance, "fmi3GetVariableDependencies", "providesPerElementDependencies=\"false\"");
}

FMI3_Export fmi3Status fmi3GetDirectionalDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[],
                                                    size_t n_unknowns, const fmi3ValueReference knowns[],
                                                    size_t n_knowns, const fmi3Float64 seed[], size_t n_seed,
                                                    fmi3Float64 sensitivity[], size_t n_sensitivity) {
    (void)unknowns; (void)n_unknowns; (void)knowns; (void)n_knowns; (void)seed; (void)n_seed; (void)sensitivity;
    (void)n_sensitivity;
    return unsupported(instance, "fmi3GetDirectionalDerivative", "providesDirectionalDerivatives=\"false\"");
}

FMI3_Export fmi3Status fmi3GetAdjointDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[],
                                                size_t n_unknowns, const fmi3ValueReference knowns[],
                                                size_t n_knowns, const fmi3Float64 seed[], size_t n_seed,
                                                fmi3Float64 sensitivity[], size_t n_sensitivity) {
    (void)unknowns; (void)n_unknowns; (void)knowns; (void)n_knowns; (void)seed; (void)n_seed; (void)sensitivity;
    (void)n_sensitivity;
    return unsupported(instance, "fmi3GetAdjointDerivative", "providesAdjointDerivatives=\"false\"");
}

FMI3_Export fmi3Status fmi3GetOutputDerivatives(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                                const fmi3Int32 orders[], fmi3Float64 values[], size_t n_values) {
    (void)vr; (void)nvr; (void)orders; (void)values; (void)n_values;
    return unsupported(instance, "fmi3GetOutputDerivatives", "maxOutputDerivativeOrder=\"0\"");
}

/* ---- FMU states: a struct copy ------------------------------------------------------------- */

FMI3_Export fmi3Status fmi3GetFMUState(fmi3Instance instance, fmi3FMUState *state) {
    fmu_instance *in = (fmu_instance *)instance;
    fmu_state_box *box;
    CHECK_STATE("fmi3GetFMUState", M_ANY);
    if (!state) return fail(in, "fmi3GetFMUState: NULL argument");
    box = (fmu_state_box *)*state; /* not NULL: a state of ours to overwrite */
    if (box && !is_our_state(box)) return fail(in, "fmi3GetFMUState: *FMUState is not an FMU state of this FMU");
    if (!box) box = (fmu_state_box *)calloc(1, sizeof *box);
    if (!box) return fail(in, "fmi3GetFMUState: out of memory");
    box->magic = STATE_MAGIC;
    snprintf(box->model, sizeof box->model, "%s", MODEL_NAME);
    box->s = in->s;
    *state = box;
    return fmi3OK;
}

FMI3_Export fmi3Status fmi3SetFMUState(fmi3Instance instance, fmi3FMUState state) {
    fmu_instance *in = (fmu_instance *)instance;
    const fmu_state_box *box = (const fmu_state_box *)state;
    CHECK_STATE("fmi3SetFMUState", M_ANY);
    if (!is_our_state(box)) return fail(in, "fmi3SetFMUState: not an FMU state of this FMU");
    in->s = box->s;
    return fmi3OK;
}

FMI3_Export fmi3Status fmi3FreeFMUState(fmi3Instance instance, fmi3FMUState *state) {
    fmu_instance *in = (fmu_instance *)instance;
    CHECK_STATE("fmi3FreeFMUState", M_ANY);
    if (!state) return fail(in, "fmi3FreeFMUState: NULL argument");
    if (*state) {
        ((fmu_state_box *)*state)->magic = 0;
        free(*state);
    }
    *state = NULL;
    return fmi3OK;
}

FMI3_Export fmi3Status fmi3SerializedFMUStateSize(fmi3Instance instance, fmi3FMUState state, size_t *size) {
    fmu_instance *in = (fmu_instance *)instance;
    CHECK_STATE("fmi3SerializedFMUStateSize", M_ANY);
    if (!state || !size) return fail(in, "fmi3SerializedFMUStateSize: NULL argument");
    *size = sizeof(fmu_state_box);
    return fmi3OK;
}

FMI3_Export fmi3Status fmi3SerializeFMUState(fmi3Instance instance, fmi3FMUState state, fmi3Byte out[],
                                             size_t size) {
    fmu_instance *in = (fmu_instance *)instance;
    const fmu_state_box *box = (const fmu_state_box *)state;
    CHECK_STATE("fmi3SerializeFMUState", M_ANY);
    if (!box || !out) return fail(in, "fmi3SerializeFMUState: NULL argument");
    if (!is_our_state(box)) return fail(in, "fmi3SerializeFMUState: not an FMU state of this FMU");
    if (size != sizeof *box)
        return fail(in, "fmi3SerializeFMUState: size = %u, expected %u", (unsigned)size, (unsigned)sizeof *box);
    memcpy(out, box, sizeof *box);
    return fmi3OK;
}

FMI3_Export fmi3Status fmi3DeserializeFMUState(fmi3Instance instance, const fmi3Byte bytes[], size_t size,
                                               fmi3FMUState *state) {
    fmu_instance *in = (fmu_instance *)instance;
    fmu_state_box box;
    CHECK_STATE("fmi3DeserializeFMUState", M_ANY);
    if (!bytes || !state) return fail(in, "fmi3DeserializeFMUState: NULL argument");
    if (size != sizeof box)
        return fail(in, "fmi3DeserializeFMUState: size = %u, expected %u (another FMU's state?)", (unsigned)size,
                    (unsigned)sizeof box);
    memcpy(&box, bytes, sizeof box);
    if (!is_our_state(&box)) return fail(in, "fmi3DeserializeFMUState: not a state of this FMU");
    if (*state && !is_our_state((const fmu_state_box *)*state))
        return fail(in, "fmi3DeserializeFMUState: *FMUState is not an FMU state of this FMU");
    if (!*state) *state = calloc(1, sizeof box);
    if (!*state) return fail(in, "fmi3DeserializeFMUState: out of memory");
    memcpy(*state, &box, sizeof box);
    return fmi3OK;
}

/* ---- Configuration Mode, Event Mode, clocks: not provided ------------------------------------- */

FMI3_Export fmi3Status fmi3EnterConfigurationMode(fmi3Instance instance) {
    return unsupported(instance, "fmi3EnterConfigurationMode", NO_STRUCTURAL);
}

FMI3_Export fmi3Status fmi3ExitConfigurationMode(fmi3Instance instance) {
    return unsupported(instance, "fmi3ExitConfigurationMode", NO_STRUCTURAL);
}

FMI3_Export fmi3Status fmi3EnterEventMode(fmi3Instance instance) {
    return unsupported(instance, "fmi3EnterEventMode", NO_EVENT_MODE);
}

FMI3_Export fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance instance) {
    return unsupported(instance, "fmi3EvaluateDiscreteStates", NO_EVENT_MODE);
}

FMI3_Export fmi3Status fmi3UpdateDiscreteStates(fmi3Instance instance, fmi3Boolean *discrete_states_need_update,
                                                fmi3Boolean *terminate_simulation,
                                                fmi3Boolean *nominals_changed, fmi3Boolean *values_changed,
                                                fmi3Boolean *next_event_time_defined, fmi3Float64 *next_event_time) {
    (void)discrete_states_need_update; (void)terminate_simulation; (void)nominals_changed; (void)values_changed;
    (void)next_event_time_defined; (void)next_event_time;
    return unsupported(instance, "fmi3UpdateDiscreteStates", NO_EVENT_MODE);
}

FMI3_Export fmi3Status fmi3EnterStepMode(fmi3Instance instance) {
    /* Step Mode is entered by fmi3ExitInitializationMode (eventModeUsed = fmi3False) */
    return unsupported(instance, "fmi3EnterStepMode", NO_EVENT_MODE);
}

FMI3_Export fmi3Status fmi3GetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                              fmi3Float64 intervals[], fmi3IntervalQualifier qualifiers[]) {
    (void)vr; (void)nvr; (void)intervals; (void)qualifiers;
    return unsupported(instance, "fmi3GetIntervalDecimal", NO_CLOCKS);
}

FMI3_Export fmi3Status fmi3GetIntervalFraction(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                               fmi3UInt64 counters[], fmi3UInt64 resolutions[],
                                               fmi3IntervalQualifier qualifiers[]) {
    (void)vr; (void)nvr; (void)counters; (void)resolutions; (void)qualifiers;
    return unsupported(instance, "fmi3GetIntervalFraction", NO_CLOCKS);
}

FMI3_Export fmi3Status fmi3GetShiftDecimal(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                           fmi3Float64 shifts[]) {
    (void)vr; (void)nvr; (void)shifts;
    return unsupported(instance, "fmi3GetShiftDecimal", NO_CLOCKS);
}

FMI3_Export fmi3Status fmi3GetShiftFraction(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                            fmi3UInt64 counters[], fmi3UInt64 resolutions[]) {
    (void)vr; (void)nvr; (void)counters; (void)resolutions;
    return unsupported(instance, "fmi3GetShiftFraction", NO_CLOCKS);
}

FMI3_Export fmi3Status fmi3SetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                              const fmi3Float64 intervals[]) {
    (void)vr; (void)nvr; (void)intervals;
    return unsupported(instance, "fmi3SetIntervalDecimal", NO_CLOCKS);
}

FMI3_Export fmi3Status fmi3SetIntervalFraction(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                               const fmi3UInt64 counters[], const fmi3UInt64 resolutions[]) {
    (void)vr; (void)nvr; (void)counters; (void)resolutions;
    return unsupported(instance, "fmi3SetIntervalFraction", NO_CLOCKS);
}

FMI3_Export fmi3Status fmi3SetShiftDecimal(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                           const fmi3Float64 shifts[]) {
    (void)vr; (void)nvr; (void)shifts;
    return unsupported(instance, "fmi3SetShiftDecimal", NO_CLOCKS);
}

FMI3_Export fmi3Status fmi3SetShiftFraction(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                            const fmi3UInt64 counters[], const fmi3UInt64 resolutions[]) {
    (void)vr; (void)nvr; (void)counters; (void)resolutions;
    return unsupported(instance, "fmi3SetShiftFraction", NO_CLOCKS);
}

FMI3_Export fmi3Status fmi3ActivateModelPartition(fmi3Instance instance, fmi3ValueReference clock,
                                                  fmi3Float64 activation_time) {
    (void)clock; (void)activation_time;
    return unsupported(instance, "fmi3ActivateModelPartition", "a Scheduled Execution function; " MODEL_NAME
                       " is a Co-Simulation FMU without clocks");
}

/* ---- Model Exchange functions: not provided ----------------------------------------------------- */

FMI3_Export fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance instance) {
    return unsupported(instance, "fmi3EnterContinuousTimeMode", ME_ONLY);
}

FMI3_Export fmi3Status fmi3CompletedIntegratorStep(fmi3Instance instance, fmi3Boolean no_set_prior,
                                                   fmi3Boolean *enter_event_mode, fmi3Boolean *terminate_simulation) {
    (void)no_set_prior; (void)enter_event_mode; (void)terminate_simulation;
    return unsupported(instance, "fmi3CompletedIntegratorStep", ME_ONLY);
}

FMI3_Export fmi3Status fmi3SetTime(fmi3Instance instance, fmi3Float64 time) {
    (void)time;
    return unsupported(instance, "fmi3SetTime", ME_ONLY);
}

FMI3_Export fmi3Status fmi3SetContinuousStates(fmi3Instance instance, const fmi3Float64 x[], size_t nx) {
    (void)x; (void)nx;
    return unsupported(instance, "fmi3SetContinuousStates", ME_ONLY);
}

FMI3_Export fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance instance, fmi3Float64 dx[], size_t nx) {
    (void)dx; (void)nx;
    return unsupported(instance, "fmi3GetContinuousStateDerivatives", ME_ONLY);
}

FMI3_Export fmi3Status fmi3GetEventIndicators(fmi3Instance instance, fmi3Float64 z[], size_t nz) {
    (void)z; (void)nz;
    return unsupported(instance, "fmi3GetEventIndicators", ME_ONLY);
}

FMI3_Export fmi3Status fmi3GetContinuousStates(fmi3Instance instance, fmi3Float64 x[], size_t nx) {
    (void)x; (void)nx;
    return unsupported(instance, "fmi3GetContinuousStates", ME_ONLY);
}

FMI3_Export fmi3Status fmi3GetNominalsOfContinuousStates(fmi3Instance instance, fmi3Float64 nominals[], size_t nx) {
    (void)nominals; (void)nx;
    return unsupported(instance, "fmi3GetNominalsOfContinuousStates", ME_ONLY);
}

FMI3_Export fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance instance, size_t *nz) {
    (void)nz;
    return unsupported(instance, "fmi3GetNumberOfEventIndicators", ME_ONLY);
}

FMI3_Export fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance instance, size_t *nx) {
    (void)nx;
    return unsupported(instance, "fmi3GetNumberOfContinuousStates", ME_ONLY);
}

/* ---- stepping ------------------------------------------------------------------------------------ */

static double time_tolerance(double t) { return 1e-9 * (fabs(t) > 1.0 ? fabs(t) : 1.0); }

/*
 * One communication step (FMI 3.0, fmi3DoStep). On fmi3OK the output arguments are:
 *   eventHandlingNeeded  fmi3False (no Event Mode);
 *   terminateSimulation  fmi3True if the FMU requests the end of the simulation: the importer
 *                        must call fmi3Terminate (a further fmi3DoStep is an error);
 *   lastSuccessfulTime   the FMU's time when fmi3DoStep returns: currentCommunicationPoint +
 *                        communicationStepSize, unless the FMU stopped before (terminateSimulation);
 *   earlyReturn          fmi3True if the FMU stopped before the end of the step and the importer
 *                        allowed an early return (earlyReturnAllowed in fmi3InstantiateCoSimulation).
 */
FMI3_Export fmi3Status fmi3DoStep(fmi3Instance instance, fmi3Float64 t, fmi3Float64 h, fmi3Boolean no_set_prior,
                                  fmi3Boolean *event_handling_needed, fmi3Boolean *terminate_simulation,
                                  fmi3Boolean *early_return, fmi3Float64 *last_successful_time) {
    fmu_instance *in = (fmu_instance *)instance;
    fmi3Status status;
    (void)no_set_prior;
    CHECK_STATE("fmi3DoStep", M_STEP);
    if (!event_handling_needed || !terminate_simulation || !early_return || !last_successful_time)
        return fail(in, "fmi3DoStep: NULL argument");
    *event_handling_needed = fmi3False;
    *terminate_simulation = in->s.terminate_requested ? fmi3True : fmi3False;
    *early_return = fmi3False;
    *last_successful_time = in->s.time;
    if (in->s.terminate_requested)
        return fail(in, "fmi3DoStep: illegal call sequence: the FMU ended the simulation at t = %.16g "
                    "(terminateSimulation = fmi3True); call fmi3Terminate", in->s.time);
    if (!(h > 0.0)) return fail(in, "fmi3DoStep: communicationStepSize = %g must be > 0", h);
    if (fabs(t - in->s.time) > time_tolerance(in->s.time))
        return fail(in, "fmi3DoStep: currentCommunicationPoint = %.16g but the FMU is at t = %.16g", t, in->s.time);
    if (in->s.stop_defined && t + h > in->s.stop_time + time_tolerance(in->s.stop_time))
        return fail(in, "fmi3DoStep: the step to t = %.16g passes stopTime = %.16g (fmi3EnterInitializationMode)",
                    t + h, in->s.stop_time);
    status = model_do_step(in, t, h);
    if (status > fmi3Warning) return status;
    *terminate_simulation = in->s.terminate_requested ? fmi3True : fmi3False;
    *last_successful_time = in->s.time;
    *early_return = (in->early_return_allowed && in->s.time < t + h - time_tolerance(t + h)) ? fmi3True : fmi3False;
    return status;
}

#endif /* TYPED3_FMU_H */
