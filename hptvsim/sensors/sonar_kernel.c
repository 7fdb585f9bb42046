/*
 * Batched multi-beam sonar ray casts: exact grid traversal plus ray-circle tests.
 *
 * Compiled at first use by hptvsim/sensors/sonar.py (gcc, cached by the hash of this file and
 * the flags) and called through ctypes on numpy arrays. sonar.py holds a numpy reference
 * implementation of the same arithmetic; the tests compare the two exactly, so any change to
 * an expression here must be mirrored there (same operations in the same order).
 *
 * Conventions (see hptvsim/world/grid.py): x north, y east, psi clockwise from north; the
 * beam direction is (cos(psi + theta), sin(psi + theta)), obtained by rotating the beam's
 * (cos theta, sin theta) by psi. Cell (i, j) is centred at (x0 + i res, y0 + j res) and covers
 * [x - res/2, x + res/2) x [y - res/2, y + res/2); cells are stored row-major, index i * ny + j.
 *
 * The grid array `cells` (uint16) holds 0xFFFF for occupied cells and, for free cells, a
 * conservative "skip" distance s = cells * quantum [m]: from any point of the cell, a ray segment
 * of length s enters no occupied cell (s = sdf - res (sqrt 2 - 1/2), rounded down to whole
 * quanta; see sonar.py). 16 bits keep the map small enough to stay in the L2 cache. The
 * traversal is Amanatides & Woo (1987), "A fast voxel traversal algorithm for ray tracing",
 * with the boundary crossing times computed in closed form from the cell index (never
 * accumulated), and with jumps of s where it exceeds `skip_min` quanta; the jumps only leave out
 * cells known to be free, so the first occupied cell and its entry distance are those of the plain
 * traversal (up to which of two cells a ray exactly through a cell corner visits).
 * A jump's landing cell needs no exactness (any cell near the landing point is free), so it
 * is computed with the cheapest arithmetic; the cell steps and the reported distances use the
 * exact closed forms shared with the reference.
 */
#include <math.h>
#include <stddef.h>
#include <stdint.h>

#define OCCUPIED 0xFFFFu

typedef struct {
    const uint16_t *cells; /* (nx, ny) */
    int64_t nx, ny;
    double x0, y0;   /* m, centre of cell (0, 0) */
    double res;      /* m */
    double ires;     /* 1/m */
    double quantum;  /* m per unit of a free cell's value */
    uint16_t skip_min; /* quanta, jump only further than this */
} grid_t;

/* clamp(trunc(xx), 0, n - 1), which equals clamp(floor(xx), 0, n - 1); |xx| must fit int64 */
static inline int64_t clamp_cell(double xx, int64_t n)
{
    int64_t i = (int64_t)xx;
    i = i < 0 ? 0 : i;
    return i >= n ? n - 1 : i;
}

/* Distance along the ray to the first occupied cell, or t_end when none is entered before it. */
static inline double cast_grid(const grid_t *g, double ox, double oy, double dx, double dy, double t_end, int *hit)
{
    const double xlo = g->x0 - 0.5 * g->res;
    const double xhi = g->x0 + ((double)g->nx - 0.5) * g->res;
    const double ylo = g->y0 - 0.5 * g->res;
    const double yhi = g->y0 + ((double)g->ny - 0.5) * g->res;
    double idx = 0.0, idy = 0.0;
    double tx_lo = -INFINITY, tx_hi = INFINITY, ty_lo = -INFINITY, ty_hi = INFINITY;
    *hit = 0;
    if (dx != 0.0) {
        idx = 1.0 / dx;
        const double ta = (xlo - ox) * idx, tb = (xhi - ox) * idx;
        tx_lo = ta < tb ? ta : tb;
        tx_hi = ta < tb ? tb : ta;
    } else if (ox < xlo || ox >= xhi) {
        return t_end;
    }
    if (dy != 0.0) {
        idy = 1.0 / dy;
        const double ta = (ylo - oy) * idy, tb = (yhi - oy) * idy;
        ty_lo = ta < tb ? ta : tb;
        ty_hi = ta < tb ? tb : ta;
    } else if (oy < ylo || oy >= yhi) {
        return t_end;
    }
    double t = 0.0;
    if (tx_lo > t) t = tx_lo;
    if (ty_lo > t) t = ty_lo;
    double t_out = t_end;
    if (tx_hi < t_out) t_out = tx_hi;
    if (ty_hi < t_out) t_out = ty_hi;
    if (!(t < t_out)) return t_end;

    const int64_t nx = g->nx, ny = g->ny;
    const int64_t si = dx > 0.0 ? 1 : -1, sj = dy > 0.0 ? 1 : -1;
    const double ofx = dx > 0.0 ? 0.5 : -0.5, ofy = dy > 0.0 ? 0.5 : -0.5;
    /* the entry cell, as in the reference (the point is in the grid, so the argument is small) */
    int64_t i = clamp_cell(((ox + t * dx) - g->x0) * g->ires + 0.5, nx);
    int64_t j = clamp_cell(((oy + t * dy) - g->y0) * g->ires + 0.5, ny);
    /* the jumps' cheaper cell arithmetic, in cell units */
    const double cx0 = (ox - g->x0) * g->ires + 0.5, cy0 = (oy - g->y0) * g->ires + 0.5;
    const double cdx = dx * g->ires, cdy = dy * g->ires;
    const int64_t max_iter = 4 * (nx + ny) + 16;
    for (int64_t it = 0; it < max_iter; ++it) {
        const uint16_t v = g->cells[i * ny + j];
        if (v == OCCUPIED) {
            *hit = 1;
            return t;
        }
        if (v > g->skip_min) {
            t += (double)v * g->quantum;
            if (t >= t_out) return t_end;
            i = clamp_cell(cx0 + t * cdx, nx);
            j = clamp_cell(cy0 + t * cdy, ny);
            continue;
        }
        const double tx = dx != 0.0 ? ((g->x0 + ((double)i + ofx) * g->res) - ox) * idx : INFINITY;
        const double ty = dy != 0.0 ? ((g->y0 + ((double)j + ofy) * g->res) - oy) * idy : INFINITY;
        if (tx <= ty) {
            t = tx;
            i += si;
            if (i < 0 || i >= nx) return t_end;
        } else {
            t = ty;
            j += sj;
            if (j < 0 || j >= ny) return t_end;
        }
        if (t >= t_out) return t_end;
    }
    return t_end; /* not reached for finite inputs */
}

/* What stays fixed between calls: the map, the beams, the maximum range (set up once). */
typedef struct {
    const uint16_t *cells; /* (nx, ny) or NULL: no terrain */
    int64_t nx, ny;
    double x0, y0, res, quantum; /* m */
    int64_t skip_min;            /* quanta */
    int64_t n_beams;
    const double *beam_cos, *beam_sin; /* (K) */
    double max_range;                  /* m */
} hptv_sonar_t;

/*
 * Cast all beams of the sensing agents of environments [b0, b1) (the caller splits work across
 * threads by environments). Arrays are C-contiguous:
 *   poses (B, N, 3) [x, y, psi]; sensing (S) agent indices whose beams are cast, or NULL (all,
 *   S = N); radii (N) or NULL (no vehicles); active (B, N) uint8 or NULL (all present; an
 *   inactive vehicle is not detected, it still senses); ranges (B, S, K) out; hit_id (B, S, K)
 *   out or NULL: -1 nothing, -2 terrain, j >= 0 vehicle j; hit_xy (B, S, K, 2) out or NULL.
 * Returns 0, or -1 when N exceeds MAXC vehicles.
 */
int hptv_sonar_cast(
    const hptv_sonar_t *sonar, int64_t b0, int64_t b1, int64_t n_agents, const double *poses,
    int64_t n_sensing, const int64_t *sensing, const double *radii, const uint8_t *active,
    double *ranges, int32_t *hit_id, double *hit_xy)
{
    const uint16_t *cells = sonar->cells;
    const int64_t n_beams = sonar->n_beams;
    const double *beam_cos = sonar->beam_cos, *beam_sin = sonar->beam_sin;
    const double max_range = sonar->max_range;
    const grid_t g = {cells,     sonar->nx,       sonar->ny,      sonar->x0,
                      sonar->y0, sonar->res,      1.0 / sonar->res, sonar->quantum,
                      (uint16_t)sonar->skip_min};
    enum { MAXC = 256 };
    double cx[MAXC], cy[MAXC], cr2[MAXC];
    int32_t cid[MAXC];
    if (radii != NULL && n_agents > MAXC) return -1;
    for (int64_t b = b0; b < b1; ++b) {
        const double *pb = poses + b * n_agents * 3;
        for (int64_t si = 0; si < n_sensing; ++si) {
            const int64_t a = sensing != NULL ? sensing[si] : si;
            const double ox = pb[a * 3 + 0], oy = pb[a * 3 + 1], psi = pb[a * 3 + 2];
            const double cp = cos(psi), sp = sin(psi);
            const int64_t ray0 = (b * n_sensing + si) * n_beams;
            int nc = 0; /* other vehicles that any beam could reach */
            if (radii != NULL) {
                for (int64_t o = 0; o < n_agents; ++o) {
                    if (o == a || (active != NULL && !active[b * n_agents + o])) continue;
                    const double fx = ox - pb[o * 3 + 0], fy = oy - pb[o * 3 + 1];
                    const double reach = max_range + radii[o];
                    if (fx * fx + fy * fy > reach * reach) continue;
                    cx[nc] = pb[o * 3 + 0];
                    cy[nc] = pb[o * 3 + 1];
                    cr2[nc] = radii[o] * radii[o];
                    cid[nc] = (int32_t)o;
                    ++nc;
                }
            }
            for (int64_t k = 0; k < n_beams; ++k) {
                const double dx = cp * beam_cos[k] - sp * beam_sin[k];
                const double dy = sp * beam_cos[k] + cp * beam_sin[k];
                double t_end = max_range;
                int32_t id = -1;
                for (int c = 0; c < nc; ++c) {
                    const double fx = ox - cx[c], fy = oy - cy[c];
                    const double bq = fx * dx + fy * dy;
                    const double cq = (fx * fx + fy * fy) - cr2[c];
                    double tc;
                    if (cq <= 0.0) {
                        tc = 0.0;
                    } else if (bq < 0.0) {
                        const double disc = bq * bq - cq;
                        if (disc < 0.0) continue;
                        tc = -bq - sqrt(disc);
                    } else {
                        continue;
                    }
                    if (tc < t_end) {
                        t_end = tc;
                        id = cid[c];
                    }
                }
                double t = t_end;
                if (cells != NULL) {
                    int hit;
                    t = cast_grid(&g, ox, oy, dx, dy, t_end, &hit);
                    if (hit) id = -2;
                }
                ranges[ray0 + k] = t;
                if (hit_id != NULL) hit_id[ray0 + k] = id;
                if (hit_xy != NULL) {
                    hit_xy[(ray0 + k) * 2 + 0] = ox + t * dx;
                    hit_xy[(ray0 + k) * 2 + 1] = oy + t * dy;
                }
            }
        }
    }
    return 0;
}

/*
 * The floor of the benchmark: the work every ray does whatever it meets (its direction and
 * storing max_range), with no traversal and no vehicle tests.
 */
int hptv_sonar_floor(const hptv_sonar_t *sonar, int64_t b0, int64_t b1, int64_t n_agents, const double *poses,
                     double *ranges)
{
    const int64_t n_beams = sonar->n_beams;
    for (int64_t b = b0; b < b1; ++b) {
        for (int64_t a = 0; a < n_agents; ++a) {
            const double *p = poses + (b * n_agents + a) * 3;
            const double cp = cos(p[2]), sp = sin(p[2]);
            double *r = ranges + (b * n_agents + a) * n_beams;
            for (int64_t k = 0; k < n_beams; ++k) {
                const double dx = cp * sonar->beam_cos[k] - sp * sonar->beam_sin[k];
                const double dy = sp * sonar->beam_cos[k] + cp * sonar->beam_sin[k];
                r[k] = sonar->max_range * (dx * dx + dy * dy);
            }
        }
    }
    return 0;
}
