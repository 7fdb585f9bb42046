/*
 * The compiled floor of hptvsim's benchmarks: an FMU's binary stepped from C, no Python.
 *
 * Usage: floor <fmu binary> <guid> <steps> <vehicles> <dt>
 *
 * Loads the FMU's shared library, instantiates <vehicles> instances and, for <steps> macro
 * steps of <dt> seconds, does for each instance what a co-simulation master must do:
 * fmi2SetReal(commands), fmi2DoStep, fmi2GetReal(pose and velocity). Then times the same
 * number of vehicle-steps through hptvsim_advance_batch (the batched backend's C entry).
 * Prints one JSON line: nanoseconds per vehicle-step for both.
 */
#define _POSIX_C_SOURCE 199309L
#include <dlfcn.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "fmi2Functions.h"

static void logger(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status, fmi2String category,
                   fmi2String message, ...) {
    (void)env;
    (void)category;
    if (status > fmi2Warning) fprintf(stderr, "[%s] %s\n", name, message);
}

static double now(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

typedef int (*advance_batch_t)(int, double *, const double *, const double *, double, double);
typedef int (*dims_t)(int *, int *, int *, int *);

#define LOAD(name) ((name##TYPE *)dlsym(lib, #name))

int main(int argc, char **argv) {
    void *lib;
    fmi2CallbackFunctions cb = {logger, calloc, free, NULL, NULL};
    fmi2Component *inst;
    fmi2ValueReference in_vr[4] = {0, 1, 5, 6};   /* v_cmd, omega_cmd, current_x, current_y */
    fmi2ValueReference out_vr[6] = {7, 8, 9, 10, 11, 12}; /* x, y, psi, u, v, r */
    double in[4] = {2.0, 0.5, 0.2, -0.1}, out[6], t = 0.0, t0, t_fmi, t_batch, sink = 0.0;
    long steps, k;
    int n, i, nx, nw, np, ny;
    double dt;
    double *x, *w, *p;
    advance_batch_t advance_batch;
    dims_t dims;

    if (argc != 6) {
        fprintf(stderr, "usage: %s <fmu binary> <guid> <steps> <vehicles> <dt>\n", argv[0]);
        return 2;
    }
    steps = atol(argv[3]);
    n = atoi(argv[4]);
    dt = atof(argv[5]);
    lib = dlopen(argv[1], RTLD_NOW | RTLD_LOCAL);
    if (!lib) {
        fprintf(stderr, "dlopen: %s\n", dlerror());
        return 1;
    }
    inst = (fmi2Component *)calloc((size_t)n, sizeof *inst);
    for (i = 0; i < n; i++) {
        inst[i] = LOAD(fmi2Instantiate)("floor", fmi2CoSimulation, argv[2], "", &cb, fmi2False, fmi2False);
        if (!inst[i]) return 1;
        LOAD(fmi2SetupExperiment)(inst[i], fmi2False, 0.0, 0.0, fmi2False, 0.0);
        LOAD(fmi2EnterInitializationMode)(inst[i]);
        LOAD(fmi2ExitInitializationMode)(inst[i]);
    }
    {
        fmi2SetRealTYPE *set_real = LOAD(fmi2SetReal);
        fmi2GetRealTYPE *get_real = LOAD(fmi2GetReal);
        fmi2DoStepTYPE *do_step = LOAD(fmi2DoStep);
        t0 = now();
        for (k = 0; k < steps; k++) {
            for (i = 0; i < n; i++) {
                if (set_real(inst[i], in_vr, 4, in) > fmi2Warning) return 1;
                if (do_step(inst[i], t, dt, fmi2True) > fmi2Warning) return 1;
                if (get_real(inst[i], out_vr, 6, out) > fmi2Warning) return 1;
                sink += out[0];
            }
            t += dt;
        }
        t_fmi = now() - t0;
    }
    advance_batch = (advance_batch_t)dlsym(lib, "hptvsim_advance_batch");
    dims = (dims_t)dlsym(lib, "hptvsim_dimensions");
    t_batch = -1.0;
    if (advance_batch && dims) {
        fmi2ValueReference pvr;
        dims(&nx, &nw, &np, &ny);
        x = (double *)calloc((size_t)n * nx, sizeof(double));
        w = (double *)calloc((size_t)n * nw, sizeof(double));
        p = (double *)calloc((size_t)n * np, sizeof(double));
        for (i = 0; i < n; i++) {
            /* parameter start values through the FMI API: Real VRs nw+ny .. nw+ny+np-2, then Integer */
            for (pvr = 0; pvr < (fmi2ValueReference)(np - 1); pvr++) {
                fmi2ValueReference vr = (fmi2ValueReference)(nw + ny) + pvr;
                LOAD(fmi2GetReal)(inst[i], &vr, 1, &p[(size_t)i * np + pvr]);
            }
            w[(size_t)i * nw + 0] = in[0];
            w[(size_t)i * nw + 1] = in[1];
            w[(size_t)i * nw + 5] = in[2];
            w[(size_t)i * nw + 6] = in[3];
        }
        t0 = now();
        for (k = 0; k < steps; k++) {
            if (advance_batch(n, x, w, p, dt, 0.01) != 0) return 1;
        }
        t_batch = now() - t0;
        sink += x[0];
    }
    printf("{\"fmi_ns_per_vehicle_step\": %.3f, \"batch_ns_per_vehicle_step\": %.3f, \"sink\": %g}\n",
           1e9 * t_fmi / ((double)steps * n), t_batch < 0 ? -1.0 : 1e9 * t_batch / ((double)steps * n), sink);
    for (i = 0; i < n; i++) LOAD(fmi2FreeInstance)(inst[i]);
    return 0;
}
