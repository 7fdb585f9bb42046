/*
 * The compiled floor of `hptvsim bench cosim`: vehicle FMUs stepped from C, no Python.
 *
 * Usage: cosim_floor <steps> <dt> <h_max> <nin> <nout> <lib> <guid> <count> <h_max_vr> [<lib> <guid> <count> <h_max_vr> ...]
 *
 * For every listed FMU binary, instantiates <count> instances with h_max set, then, for <steps>
 * macro steps of <dt> seconds, does for each instance what a co-simulation master must do:
 * fmi2SetReal of the <nin> inputs (value references 0..nin-1), fmi2DoStep, fmi2GetReal of the
 * <nout> outputs (value references nin..nin+nout-1). Then times the same vehicle-steps through
 * the binaries' batch entries (hptvsim_advance_batch + hptvsim_output_batch), one call per
 * binary and step. Prints one JSON line: nanoseconds per vehicle-step for both.
 */
#define _POSIX_C_SOURCE 199309L
#include <dlfcn.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "fmi2Functions.h"

#define MAX_LIBS 8

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
typedef void (*output_batch_t)(int, const double *, const double *, const double *, double *);
typedef int (*dims_t)(int *, int *, int *, int *);

typedef struct {
    void *lib;
    int count;
    fmi2Component *inst;
    fmi2SetRealTYPE *set_real;
    fmi2GetRealTYPE *get_real;
    fmi2GetIntegerTYPE *get_integer;
    fmi2DoStepTYPE *do_step;
    fmi2FreeInstanceTYPE *free_instance;
    advance_batch_t advance;
    output_batch_t output;
    double *x, *w, *p, *y;
} fleet;

int main(int argc, char **argv) {
    fmi2CallbackFunctions cb = {logger, calloc, free, NULL, NULL};
    fleet f[MAX_LIBS];
    fmi2ValueReference in_vr[32], out_vr[32];
    double in[32], out[32], t = 0.0, t0, t_fmi, t_batch, sink = 0.0, dt, h_max;
    long steps, k, total = 0;
    int nlib, nin, nout, i, j, l, nx, nw, np, ny;

    if (argc < 10 || (argc - 6) % 4 != 0) {
        fprintf(stderr, "usage: %s <steps> <dt> <h_max> <nin> <nout> (<lib> <guid> <count> <h_max_vr>)+\n",
                argv[0]);
        return 2;
    }
    steps = atol(argv[1]);
    dt = atof(argv[2]);
    h_max = atof(argv[3]);
    nin = atoi(argv[4]);
    nout = atoi(argv[5]);
    nlib = (argc - 6) / 4;
    if (nlib > MAX_LIBS || nin > 32 || nout > 32) return 2;
    for (j = 0; j < nin; j++) {
        in_vr[j] = (fmi2ValueReference)j;
        in[j] = 0.0;
    }
    in[0] = 2.0;  /* v_cmd [m/s] */
    in[1] = 0.5;  /* omega_cmd [rad/s] */
    if (nin > 6) {
        in[5] = 0.2;   /* current_x [m/s] */
        in[6] = -0.1;  /* current_y [m/s] */
    }
    for (j = 0; j < nout; j++) out_vr[j] = (fmi2ValueReference)(nin + j);

    for (l = 0; l < nlib; l++) {
        const char *path = argv[6 + 4 * l];
        const char *guid = argv[7 + 4 * l];
        fmi2ValueReference hvr = (fmi2ValueReference)atoi(argv[9 + 4 * l]);
        fmi2InstantiateTYPE *instantiate;
        fleet *F = &f[l];
        F->count = atoi(argv[8 + 4 * l]);
        F->lib = dlopen(path, RTLD_NOW | RTLD_LOCAL);
        if (!F->lib) {
            fprintf(stderr, "dlopen: %s\n", dlerror());
            return 1;
        }
        instantiate = (fmi2InstantiateTYPE *)dlsym(F->lib, "fmi2Instantiate");
        F->set_real = (fmi2SetRealTYPE *)dlsym(F->lib, "fmi2SetReal");
        F->get_real = (fmi2GetRealTYPE *)dlsym(F->lib, "fmi2GetReal");
        F->get_integer = (fmi2GetIntegerTYPE *)dlsym(F->lib, "fmi2GetInteger");
        F->do_step = (fmi2DoStepTYPE *)dlsym(F->lib, "fmi2DoStep");
        F->free_instance = (fmi2FreeInstanceTYPE *)dlsym(F->lib, "fmi2FreeInstance");
        F->advance = (advance_batch_t)dlsym(F->lib, "hptvsim_advance_batch");
        F->output = (output_batch_t)dlsym(F->lib, "hptvsim_output_batch");
        F->inst = (fmi2Component *)calloc((size_t)F->count, sizeof *F->inst);
        for (i = 0; i < F->count; i++) {
            fmi2Component c = instantiate("floor", fmi2CoSimulation, guid, "", &cb, fmi2False, fmi2False);
            if (!c) return 1;
            ((fmi2SetupExperimentTYPE *)dlsym(F->lib, "fmi2SetupExperiment"))(c, fmi2False, 0.0, 0.0, fmi2False, 0.0);
            ((fmi2EnterInitializationModeTYPE *)dlsym(F->lib, "fmi2EnterInitializationMode"))(c);
            if (F->set_real(c, &hvr, 1, &h_max) > fmi2Warning) return 1;
            ((fmi2ExitInitializationModeTYPE *)dlsym(F->lib, "fmi2ExitInitializationMode"))(c);
            F->inst[i] = c;
        }
        total += F->count;
    }

    t0 = now();
    for (k = 0; k < steps; k++) {
        for (l = 0; l < nlib; l++) {
            fleet *F = &f[l];
            for (i = 0; i < F->count; i++) {
                if (F->set_real(F->inst[i], in_vr, (size_t)nin, in) > fmi2Warning) return 1;
                if (F->do_step(F->inst[i], t, dt, fmi2True) > fmi2Warning) return 1;
                if (F->get_real(F->inst[i], out_vr, (size_t)nout, out) > fmi2Warning) return 1;
                sink += out[0];
            }
        }
        t += dt;
    }
    t_fmi = now() - t0;

    t_batch = -1.0;
    for (l = 0; l < nlib; l++) {
        fleet *F = &f[l];
        dims_t dims = (dims_t)dlsym(F->lib, "hptvsim_dimensions");
        if (!F->advance || !F->output || !dims) break;
        dims(&nx, &nw, &np, &ny);
        F->x = (double *)calloc((size_t)F->count * nx, sizeof(double));
        F->w = (double *)calloc((size_t)F->count * nw, sizeof(double));
        F->p = (double *)calloc((size_t)F->count * np, sizeof(double));
        F->y = (double *)calloc((size_t)F->count * ny, sizeof(double));
        for (i = 0; i < F->count; i++) {
            /* parameter values through the FMI API: Real VRs nw+ny .. nw+ny+np-2, then the Integer */
            fmi2ValueReference vr0 = (fmi2ValueReference)(nw + ny), ivr = 0;
            fmi2Integer mode = 0;
            fmi2ValueReference vrs[64];
            for (j = 0; j < np - 1; j++) vrs[j] = vr0 + (fmi2ValueReference)j;
            F->get_real(F->inst[i], vrs, (size_t)(np - 1), &F->p[(size_t)i * np]);
            ivr = vr0 + (fmi2ValueReference)(np - 1) + 6 + 1; /* after the 6 initial values and h_max */
            F->get_integer(F->inst[i], &ivr, 1, &mode);
            F->p[(size_t)i * np + np - 1] = (double)mode;
            for (j = 0; j < nin && j < nw; j++) F->w[(size_t)i * nw + j] = in[j];
        }
    }
    if (l == nlib) {
        for (l = 0; l < nlib; l++) { /* warm-up step: page faults, lazy symbol binding */
            if (f[l].advance(f[l].count, f[l].x, f[l].w, f[l].p, dt, h_max) != 0) return 1;
            f[l].output(f[l].count, f[l].x, f[l].w, f[l].p, f[l].y);
        }
        t0 = now();
        for (k = 0; k < steps; k++) {
            for (l = 0; l < nlib; l++) {
                fleet *F = &f[l];
                if (F->advance(F->count, F->x, F->w, F->p, dt, h_max) != 0) return 1;
                F->output(F->count, F->x, F->w, F->p, F->y);
            }
        }
        t_batch = now() - t0;
        sink += f[0].y[0];
    }
    printf("{\"fmi_ns_per_vehicle_step\": %.3f, \"batch_ns_per_vehicle_step\": %.3f, \"sink\": %g}\n",
           1e9 * t_fmi / ((double)steps * (double)total),
           t_batch < 0 ? -1.0 : 1e9 * t_batch / ((double)steps * (double)total), sink);
    for (l = 0; l < nlib; l++)
        for (i = 0; i < f[l].count; i++) f[l].free_instance(f[l].inst[i]);
    return 0;
}
