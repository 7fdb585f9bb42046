/* A minimal FMI 2.0 Co-Simulation importer in C, for running an FMU's binary on any platform
 * (natively, or its win64 DLL under Wine): load the library, instantiate, set Real inputs, step,
 * print Real outputs after every step.
 *
 * usage: fmu_run LIBRARY GUID RESOURCE_URI STEP_SIZE STEPS "vr=value,..." "vr,vr,..."
 * prints: one line per step, "time,out_1,out_2,..." with 17 significant digits.
 */
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"

#ifdef _WIN32
#include <windows.h>
typedef HMODULE lib_t;
static lib_t lib_open(const char *path) { return LoadLibraryA(path); }
static void *lib_sym(lib_t lib, const char *name) { return (void *)GetProcAddress(lib, name); }
#else
#include <dlfcn.h>
typedef void *lib_t;
static lib_t lib_open(const char *path) { return dlopen(path, RTLD_NOW | RTLD_LOCAL); }
static void *lib_sym(lib_t lib, const char *name) { return dlsym(lib, name); }
#endif

static void logger(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status, fmi2String category,
                   fmi2String message, ...) {
    va_list args;
    va_start(args, message);
    fprintf(stderr, "[%s] ", category ? category : "");
    vfprintf(stderr, message, args);
    fprintf(stderr, "\n");
    va_end(args);
}

#define SYM(type, name)                                                   \
    type name = (type)lib_sym(lib, #name);                                \
    if (!name) {                                                          \
        fprintf(stderr, "the library does not export %s\n", #name);      \
        return 2;                                                         \
    }

#define CHECK(call)                                                       \
    if ((call) > fmi2Warning) {                                           \
        fprintf(stderr, "%s failed\n", #call);                            \
        return 3;                                                         \
    }

static int parse_list(const char *text, fmi2ValueReference *vrs, double *values, int max) {
    int n = 0;
    const char *p = text;
    while (*p && n < max) {
        char *end;
        vrs[n] = (fmi2ValueReference)strtoul(p, &end, 10);
        if (end == p) break;
        p = end;
        if (values) {
            if (*p != '=') return -1;
            values[n] = strtod(p + 1, &end);
            p = end;
        }
        n++;
        if (*p == ',') p++;
    }
    return n;
}

int main(int argc, char **argv) {
    if (argc != 8) {
        fprintf(stderr, "usage: %s LIBRARY GUID RESOURCE_URI STEP_SIZE STEPS \"vr=value,...\" \"vr,...\"\n", argv[0]);
        return 1;
    }
    lib_t lib = lib_open(argv[1]);
    if (!lib) {
        fprintf(stderr, "cannot load %s\n", argv[1]);
        return 2;
    }
    SYM(fmi2InstantiateTYPE *, fmi2Instantiate)
    SYM(fmi2SetupExperimentTYPE *, fmi2SetupExperiment)
    SYM(fmi2EnterInitializationModeTYPE *, fmi2EnterInitializationMode)
    SYM(fmi2ExitInitializationModeTYPE *, fmi2ExitInitializationMode)
    SYM(fmi2SetRealTYPE *, fmi2SetReal)
    SYM(fmi2GetRealTYPE *, fmi2GetReal)
    SYM(fmi2DoStepTYPE *, fmi2DoStep)
    SYM(fmi2TerminateTYPE *, fmi2Terminate)
    SYM(fmi2FreeInstanceTYPE *, fmi2FreeInstance)
    double h = strtod(argv[4], NULL);
    int steps = atoi(argv[5]);
    fmi2ValueReference in_vr[64], out_vr[64];
    double in_val[64], out_val[64];
    int n_in = parse_list(argv[6], in_vr, in_val, 64);
    int n_out = parse_list(argv[7], out_vr, NULL, 64);
    if (n_in < 0 || n_out <= 0) {
        fprintf(stderr, "bad input or output list\n");
        return 1;
    }
    fmi2CallbackFunctions callbacks = {logger, calloc, free, NULL, NULL};
    fmi2Component c = fmi2Instantiate("harness", fmi2CoSimulation, argv[2], argv[3], &callbacks, fmi2False, fmi2False);
    if (!c) {
        fprintf(stderr, "fmi2Instantiate failed\n");
        return 3;
    }
    CHECK(fmi2SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0))
    CHECK(fmi2EnterInitializationMode(c))
    CHECK(fmi2ExitInitializationMode(c))
    if (n_in > 0) CHECK(fmi2SetReal(c, in_vr, (size_t)n_in, in_val))
    for (int k = 0; k < steps; k++) {
        CHECK(fmi2DoStep(c, k * h, h, fmi2True))
        CHECK(fmi2GetReal(c, out_vr, (size_t)n_out, out_val))
        printf("%.17g", (k + 1) * h);
        for (int i = 0; i < n_out; i++) printf(",%.17g", out_val[i]);
        printf("\n");
    }
    CHECK(fmi2Terminate(c))
    fmi2FreeInstance(c);
    return 0;
}
