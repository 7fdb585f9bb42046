/*
 * The UPEG task layer in C: target geometry, observation (Eq. 14), reward (Eqs. 17-20) and
 * end rules, for environments b0 <= b < b1 of a batch of B environments x N agents.
 *
 * Part of hptvsim (Apache-2.0). The readable reference is hptvsim/envs/task.py (and the signed
 * distance lookup OccupancyGrid.distance in hptvsim/world/grid.py); this file performs the same
 * floating-point operations in the same order, so the tests require the two to agree exactly.
 * Arrays are C-contiguous, row-major: (B, N, ...) per environment and agent.
 */
#include <math.h>
#include <stddef.h>
#include <stdint.h>

typedef struct {
    int64_t B, N, K, obs_size, extended, goto_task, max_steps;
    double max_range, diagonal, site_x, site_y;
    double safe_distance, target_distance;
    double delta_C, delta_E1, delta_E2, collision_penalty, progress_reward, capture_reward;
    double crash_penalty; /* subtracted when the agent's own collision or exit ends the episode */
    const uint8_t *pursuer;    /* (N,) */
    const double *radii;       /* (N,) m */
    const double *limits;      /* (N, 2): v_max [m/s], omega_max [rad/s] (extended only) */
    const double *cmd_limits;  /* (N, 3): v_min, v_max [m/s], omega_max [rad/s] (Eq. 15) */
    const double *goal_radius; /* (N,) m */
    const double *sdf;         /* (nx, ny) m, signed distance field of the obstacle map */
    int64_t nx, ny;
    double x0, y0, res;
} hptv_task_t;

typedef struct {
    const double *pos;           /* (B, N, 2) m */
    const double *yaw;           /* (B, N) rad */
    const double *vel;           /* (B, N, 3) u, v [m/s], r [rad/s] */
    const double *ranges;        /* (B, N, K) m, as measured */
    const double *goals;         /* (B, N, 2) m, goto only, else NULL */
    const double *reported;      /* (B, N, 2) m, the target each pursuer knows, or NULL */
    const double *prev_distance; /* (B, N) m */
    const int64_t *steps;        /* (B,) */
    float *obs;                  /* (B, N, obs_size) out */
    double *distance;            /* (B, N) m out: true distance to the target */
    double *r_C, *r_E1, *r_E2, *total; /* (B, N) out */
    double *terrain;             /* (B, N) m out: signed distance to terrain at each centre */
    uint8_t *captured;           /* (B,) out */
    uint8_t *reached;            /* (B, N) out */
    uint8_t *collision;          /* (B, N) out */
    uint8_t *out_of_site;        /* (B, N) out */
    uint8_t *truncated;          /* (B,) out */
    /* bookkeeping (task.bookkeeping); skipped when active == NULL */
    uint8_t *active;             /* (B, N) in/out: agents still in their episode */
    uint8_t *done;               /* (B,) in/out: environments whose episode is over */
    uint8_t *newly_done;         /* (B,) out */
    uint8_t *terminated_agent;   /* (B, N) out */
    uint8_t *truncated_agent;    /* (B, N) out */
    double *reward;              /* (B, N) out: total where the agent acted, else 0 */
    double *episode_return;      /* (B, N) in/out */
} hptv_task_io_t;

static const double PI = 3.14159265358979311600;     /* math.pi */
static const double TWO_PI = 6.28318530717958623200; /* 2 * math.pi */

/* numpy's float remainder (the sign of the divisor), as in wrap(): (a + pi) % (2 pi) - pi */
static double wrap(double a) {
    double r = fmod(a + PI, TWO_PI);
    if (r != 0.0 && ((r < 0.0) != (TWO_PI < 0.0))) r += TWO_PI;
    return r - PI;
}

static double clip(double v, double lo, double hi) { return v < lo ? lo : (v > hi ? hi : v); }

/* OccupancyGrid.distance: bilinear between cell centres, clamped to the grid. */
static double sdf_at(const hptv_task_t *t, double x, double y) {
    double fi, fj, ti, tj, top, bottom;
    int64_t i0, j0, i1, j1, imax, jmax;
    if (!isfinite(t->sdf[0])) return t->sdf[0]; /* no obstacle (+inf) or all occupied (-inf) */
    fi = clip((x - t->x0) / t->res, 0.0, (double)t->nx - 1.0);
    fj = clip((y - t->y0) / t->res, 0.0, (double)t->ny - 1.0);
    imax = t->nx - 2 > 0 ? t->nx - 2 : 0;
    jmax = t->ny - 2 > 0 ? t->ny - 2 : 0;
    i0 = (int64_t)floor(fi);
    j0 = (int64_t)floor(fj);
    if (i0 > imax) i0 = imax;
    if (j0 > jmax) j0 = jmax;
    i1 = i0 + 1 < t->nx - 1 ? i0 + 1 : t->nx - 1;
    j1 = j0 + 1 < t->ny - 1 ? j0 + 1 : t->ny - 1;
    ti = fi - (double)i0;
    tj = fj - (double)j0;
    top = t->sdf[i0 * t->ny + j0] * (1.0 - tj) + t->sdf[i0 * t->ny + j1] * tj;
    bottom = t->sdf[i1 * t->ny + j0] * (1.0 - tj) + t->sdf[i1 * t->ny + j1] * tj;
    return top * (1.0 - ti) + bottom * ti;
}

int hptv_task_eval(const hptv_task_t *t, const hptv_task_io_t *io, int64_t b0, int64_t b1) {
    const int64_t N = t->N, K = t->K;
    int64_t b, i, j, k;
    if (N > 256) return 1;
    for (b = b0; b < b1; b++) {
        const double *pos = io->pos + b * N * 2;
        uint8_t any_capture = 0;
        for (i = 0; i < N; i++) {
            /* --- target_geometry ---------------------------------------------------------- */
            double d_true, tx, ty, ox, oy;
            if (t->goto_task) {
                const double *g = io->goals + (b * N + i) * 2;
                double dx = g[0] - pos[2 * i], dy = g[1] - pos[2 * i + 1];
                d_true = sqrt(dx * dx + dy * dy);
                tx = g[0];
                ty = g[1];
            } else {
                int64_t best = -1;
                double best_d = INFINITY;
                for (j = 0; j < N; j++) {
                    double dx, dy, d;
                    if (t->pursuer[i] == t->pursuer[j]) continue;
                    dx = pos[2 * i] - pos[2 * j];
                    dy = pos[2 * i + 1] - pos[2 * j + 1];
                    d = sqrt(dx * dx + dy * dy);
                    if (d < best_d) {
                        best_d = d;
                        best = j;
                    }
                }
                if (best < 0) return 2;
                d_true = best_d;
                tx = pos[2 * best];
                ty = pos[2 * best + 1];
            }
            io->distance[b * N + i] = d_true;
            ox = tx;
            oy = ty;
            if (!t->goto_task && io->reported != NULL && t->pursuer[i]) {
                ox = io->reported[(b * N + i) * 2];
                oy = io->reported[(b * N + i) * 2 + 1];
            }
            /* --- observations (Eq. 14) ----------------------------------------------------- */
            {
                float *o = io->obs + (b * N + i) * t->obs_size;
                const double *r = io->ranges + (b * N + i) * K;
                const double inv_range = 1.0 / t->max_range;
                double dx = ox - pos[2 * i], dy = oy - pos[2 * i + 1];
                double d_obs = hypot(dx, dy), rmin = r[0], psi, azimuth;
                for (k = 0; k < K; k++) {
                    o[k] = (float)clip(r[k] * inv_range, 0.0, 1.0);
                    if (r[k] < rmin) rmin = r[k];
                }
                {
                    double q = d_obs / t->diagonal;
                    o[K] = (float)(q < 1.0 ? q : 1.0);
                }
                o[K + 1] = (float)clip(rmin * inv_range, 0.0, 1.0);
                psi = wrap(io->yaw[b * N + i]);
                azimuth = atan2(dy, dx);
                o[K + 2] = (float)(psi / PI);
                o[K + 3] = (float)(wrap(azimuth) / PI);
                if (t->extended) {
                    const double *v = io->vel + (b * N + i) * 3;
                    double rel = azimuth - psi;
                    o[K + 4] = (float)sin(rel);
                    o[K + 5] = (float)cos(rel);
                    o[K + 6] = (float)clip(v[0] / t->limits[2 * i], -1.0, 1.0);
                    o[K + 7] = (float)clip(v[2] / t->limits[2 * i + 1], -1.0, 1.0);
                    o[K + 8] = (float)clip(pos[2 * i] / t->site_x, -1.0, 1.0);
                    o[K + 9] = (float)clip(pos[2 * i + 1] / t->site_y, -1.0, 1.0);
                }
                /* --- reward (Eqs. 17-20) ----------------------------------------------------- */
                {
                    double prev = io->prev_distance[b * N + i];
                    double diff = prev - d_true;
                    double closer = diff > 0.0 ? 1.0 : (diff < 0.0 ? -1.0 : (diff == 0.0 ? 0.0 : diff));
                    double rc = rmin <= t->safe_distance ? -t->collision_penalty : 0.0;
                    double re1, re2;
                    if (t->goto_task) {
                        re1 = t->progress_reward * closer;
                        re2 = d_true <= t->goal_radius[i] ? t->capture_reward : 0.0;
                    } else if (t->pursuer[i]) {
                        re1 = t->progress_reward * closer;
                        re2 = d_true <= t->target_distance ? t->capture_reward : 0.0;
                    } else {
                        re1 = t->progress_reward * -closer;
                        re2 = d_true <= t->target_distance ? -t->capture_reward : 0.0;
                    }
                    io->r_C[b * N + i] = rc;
                    io->r_E1[b * N + i] = re1;
                    io->r_E2[b * N + i] = re2;
                    io->total[b * N + i] = t->delta_C * rc + t->delta_E1 * re1 + t->delta_E2 * re2;
                }
            }
            /* --- end rules ------------------------------------------------------------------ */
            {
                double x = pos[2 * i], y = pos[2 * i + 1];
                double terrain = sdf_at(t, x, y);
                uint8_t hit = terrain < t->radii[i];
                for (j = 0; j < N && !hit; j++) {
                    double dx, dy, gap;
                    if (j == i) continue;
                    dx = x - pos[2 * j];
                    dy = y - pos[2 * j + 1];
                    gap = sqrt(dx * dx + dy * dy) - (t->radii[i] + t->radii[j]);
                    if (gap < 0.0) hit = 1;
                }
                io->terrain[b * N + i] = terrain;
                io->collision[b * N + i] = hit;
                io->out_of_site[b * N + i] = (x < 0.0) | (x > t->site_x) | (y < 0.0) | (y > t->site_y);
                if (t->goto_task) {
                    io->reached[b * N + i] = d_true <= t->goal_radius[i];
                } else {
                    io->reached[b * N + i] = 0;
                    if (t->pursuer[i] && d_true <= t->target_distance) any_capture = 1;
                }
            }
        }
        io->captured[b] = any_capture;
        io->truncated[b] = io->steps[b] >= t->max_steps;
        /* --- bookkeeping ----------------------------------------------------------------- */
        if (io->active != NULL) {
            uint8_t was_done = io->done[b], fail = 0, ends_all, any_still = 0;
            for (i = 0; i < N; i++) fail |= io->collision[b * N + i] | io->out_of_site[b * N + i];
            ends_all = any_capture | fail;
            for (i = 0; i < N; i++) {
                const int64_t k = b * N + i;
                uint8_t acted = io->active[k] && !was_done;
                uint8_t term = acted && (ends_all || io->reached[k]);
                uint8_t trunc = acted && !term && io->truncated[b];
                uint8_t crashed = io->collision[k] | io->out_of_site[k];
                double r = acted ? io->total[k] - (crashed ? t->crash_penalty : 0.0) : 0.0;
                io->reward[k] = r;
                io->terminated_agent[k] = term;
                io->truncated_agent[k] = trunc;
                io->active[k] = io->active[k] && !(term || trunc);
                io->episode_return[k] += r;
                any_still |= io->active[k];
            }
            io->newly_done[b] = !was_done && !any_still;
            io->done[b] = was_done || io->newly_done[b];
        }
    }
    return 0;
}

/* Clip actions (B, N, 2) to each agent's box (Eq. 15) and write them into the vehicle inputs
 * (B, N, stride) columns 0-1 (v_cmd, omega_cmd); agents not active (or whole environments done)
 * get [0, 0]. The same as np.clip per column followed by zeroing the inactive rows. */
void hptv_task_commands(const hptv_task_t *t, const double *actions, const uint8_t *active, double *inputs,
                        int64_t stride, int64_t b0, int64_t b1) {
    const int64_t N = t->N;
    int64_t b, i;
    for (b = b0; b < b1; b++) {
        for (i = 0; i < N; i++) {
            const int64_t k = b * N + i;
            double *w = inputs + k * stride;
            if (!active[k]) {
                w[0] = 0.0;
                w[1] = 0.0;
            } else {
                w[0] = clip(actions[2 * k], t->cmd_limits[3 * i], t->cmd_limits[3 * i + 1]);
                w[1] = clip(actions[2 * k + 1], -t->cmd_limits[3 * i + 2], t->cmd_limits[3 * i + 2]);
            }
        }
    }
}
