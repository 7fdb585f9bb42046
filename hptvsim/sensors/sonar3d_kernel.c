/*
 * Batched 3-D multibeam sonar ray casts: an exact march over a bilinear seabed plus ray-sphere tests.
 *
 * Compiled at first use by hptvsim/sensors/sonar3d.py (gcc, cached by the hash of this file and
 * the flags) and called through ctypes on numpy arrays. sonar3d.py holds a numpy reference
 * (cast_reference_3d) of the same arithmetic, which visits every patch; the tests compare the
 * two, so a change to an expression here must be mirrored there.
 *
 * Conventions (NED, Fossen 2021 ch. 2): x north, y east, z down [m]; a pose is
 * [x, y, z, phi, theta, psi], the body-to-NED rotation R = Rz(psi) Ry(theta) Rx(phi) (Fossen 2021,
 * Eq. 2.18), and a beam's NED direction is R b for its body-frame unit vector b.
 *
 * The seabed. depth[i * ny + j] [m, positive down] is the depth at the centre of cell (i, j),
 * (x0 + i res, y0 + j res). The surface is the bilinear interpolation between cell centres,
 * clamped at the edge (the half cell around the grid takes the edge cells' values), defined over
 * the grid's extent [x0 - res/2, x0 + (nx - 1/2) res] x [...]. In cell units fx = (x - x0) / res
 * the extent is split at the centres fx = 0, 1, ..., nx - 1 into the patches p = 0 .. nx:
 * patch p spans [lo(p), hi(p)] with lo(0) = -1/2, lo(p) = p - 1, hi(p) = p, hi(nx) = nx - 1/2,
 * and interpolates between cells i0 = max(p - 1, 0) and i1 = min(p, nx - 1) (the same cell at the
 * two clamped edge patches); likewise along y. Over a patch the depth is
 *     D(u, v) = d00 + b u + c v + e u v,   u = fx - i0, v = fy - j0,
 *     b = d10 - d00, c = d01 - d00, e = (d11 - d01) - (d10 - d00),
 * which is a plane wherever the four samples lie on one, and constant across a clamped patch.
 *
 * The march. A 2-D DDA (Amanatides & Woo 1987) visits, in order, every patch the ray's ground
 * track crosses; the boundary crossing times are computed in closed form from the patch index
 * (never accumulated). Along the ray's segment [ta, tb] in a patch, f(s) = D - z (seabed minus the
 * ray's depth, s = t - ta) is the quadratic A + B s + C s^2, solved for its first root in
 * [0, tb - ta] with the cancellation-free formula; f(0) <= 0 is a hit at ta (the ray starts, or
 * enters the grid, at or below the seabed). Every patch crossed is tested exactly, so no ridge
 * can be tunnelled through.
 *
 * Speed. The bilinear surface's minimum over a patch is at a corner, so a ray whose deepest point
 * over a segment is shallower than the shallowest depth sample there cannot meet the seabed on it.
 * The march is two-level: a DDA over blocks of 2^shift x 2^shift patches passes over each block
 * the ray stays above (block_min, computed once by sonar3d.block_minima) and visits the patches
 * of the others; there a patch the ray stays above is passed over without the solve; and a ray
 * that stays above the whole map's shallowest sample is not marched at all. The block boundaries
 * are patch boundaries, with the same closed forms, so the patches solved and their segments are
 * those of the plain march.
 *
 * Ends of a ray, nearest first: another vehicle (a sphere), the seabed, the sea surface (a ray that
 * rises to z = 0 ends there with no return; a sonar above the surface, z < 0, hears nothing),
 * leaving the grid (no seabed outside: nothing more to hit), or max_range.
 */
#include <math.h>
#include <stddef.h>
#include <stdint.h>

/* What stays fixed between calls: the seabed, the beams, the range window (set up once). */
typedef struct {
    const double *depth;     /* (nx, ny) m, positive down; NULL: no seabed */
    const double *block_min; /* (nbx, nby) m, shallowest sample of each block of patches */
    int64_t nx, ny;          /* cells */
    int64_t block_shift;     /* log2 of the patches per block side */
    int64_t nbx, nby;        /* blocks: (nx >> block_shift) + 1, (ny >> block_shift) + 1 */
    double shallowest;       /* m, the shallowest depth sample of the whole map */
    double x0, y0, res;      /* m */
    int64_t n_beams;
    const double *beams;         /* (K, 3) body-frame unit vectors */
    double max_range, min_range; /* m */
} hptv_sonar3d_t;

typedef struct {
    const double *depth, *block_min;
    int64_t nx, ny, shift, nby;
} seabed_t;

static inline double lo_edge(int64_t p) { return p == 0 ? -0.5 : (double)(p - 1); }
static inline double hi_edge(int64_t p, int64_t n) { return p == n ? (double)n - 0.5 : (double)p; }

/* The patch (0 .. n) holding coordinate c [cells], the one ahead when c lies on a boundary. */
static inline int64_t patch_of(double c, double g, int64_t n)
{
    double p = g >= 0.0 ? floor(c) + 1.0 : ceil(c);
    p = p < 0.0 ? 0.0 : p; /* clamp in floating point: any finite c is safe */
    p = p > (double)n ? (double)n : p;
    return (int64_t)p;
}

/*
 * First t in [ta, tb] where the ray is at or below the patch (p, q): 1 and *t_hit, or 0.
 * Ray: fx = fx0 + t gx, fy = fy0 + t gy [cells], z = oz + t dz [m].
 */
static inline int patch_hit(const seabed_t *s, int64_t p, int64_t q, double fx0, double fy0, double gx, double gy,
                            double oz, double dz, double ta, double tb, double *t_hit)
{
    const int64_t i0 = p > 0 ? p - 1 : 0, i1 = p < s->nx ? p : s->nx - 1;
    const int64_t j0 = q > 0 ? q - 1 : 0, j1 = q < s->ny ? q : s->ny - 1;
    const double d00 = s->depth[i0 * s->ny + j0], d01 = s->depth[i0 * s->ny + j1];
    const double d10 = s->depth[i1 * s->ny + j0], d11 = s->depth[i1 * s->ny + j1];
    const double za = oz + ta * dz, zb = oz + tb * dz;
    const double zmax = za > zb ? za : zb;
    double dmin = d00 < d01 ? d00 : d01;
    dmin = d10 < dmin ? d10 : dmin;
    dmin = d11 < dmin ? d11 : dmin;
    if (zmax < dmin) return 0; /* the ray stays above the patch's shallowest corner */
    const double u = (fx0 + ta * gx) - (double)i0, v = (fy0 + ta * gy) - (double)j0;
    const double b = d10 - d00, c = d01 - d00, e = (d11 - d01) - (d10 - d00);
    const double a = (d00 + b * u + c * v + e * u * v) - za;
    if (a <= 0.0) {
        *t_hit = ta;
        return 1;
    }
    const double bq = (b * gx + c * gy + e * (u * gy + v * gx)) - dz;
    const double cq = e * gx * gy;
    double root;
    if (cq == 0.0) {
        if (!(bq < 0.0)) return 0;
        root = -a / bq;
    } else {
        const double disc = bq * bq - 4.0 * a * cq;
        if (disc < 0.0) return 0;
        const double h = -0.5 * (bq + copysign(sqrt(disc), bq)); /* never 0: a > 0 */
        const double r1 = h / cq, r2 = a / h;
        const double first = r1 < r2 ? r1 : r2, second = r1 < r2 ? r2 : r1;
        root = first >= 0.0 ? first : second;
        if (!(root >= 0.0)) return 0;
    }
    if (!(root <= tb - ta)) return 0;
    *t_hit = ta + root;
    return 1;
}

/*
 * Distance along the ray to the seabed, if the seabed is met before t_lim: 1 and *t_hit; else 0.
 * In cells: fx0 = (ox - x0) / res, gx = dx / res (likewise y); oz, dz in metres.
 */
static int cast_seabed(const seabed_t *s, double fx0, double fy0, double oz, double gx, double gy, double dz,
                       double t_lim, double *t_hit)
{
    const int64_t nx = s->nx, ny = s->ny, sh = s->shift, bs = (int64_t)1 << sh;
    const int64_t bx_max = nx >> sh, by_max = ny >> sh; /* last block along each axis */
    const double ex_hi = (double)nx - 0.5, ey_hi = (double)ny - 0.5;
    double igx = 0.0, igy = 0.0;
    double tx_lo = -HUGE_VAL, tx_hi = HUGE_VAL, ty_lo = -HUGE_VAL, ty_hi = HUGE_VAL;
    if (gx != 0.0) {
        igx = 1.0 / gx;
        const double ta = (-0.5 - fx0) * igx, tb = (ex_hi - fx0) * igx;
        tx_lo = ta < tb ? ta : tb;
        tx_hi = ta < tb ? tb : ta;
    } else if (fx0 < -0.5 || fx0 > ex_hi) {
        return 0;
    }
    if (gy != 0.0) {
        igy = 1.0 / gy;
        const double ta = (-0.5 - fy0) * igy, tb = (ey_hi - fy0) * igy;
        ty_lo = ta < tb ? ta : tb;
        ty_hi = ta < tb ? tb : ta;
    } else if (fy0 < -0.5 || fy0 > ey_hi) {
        return 0;
    }
    double t = 0.0;
    if (tx_lo > t) t = tx_lo;
    if (ty_lo > t) t = ty_lo;
    double t_out = t_lim;
    if (tx_hi < t_out) t_out = tx_hi;
    if (ty_hi < t_out) t_out = ty_hi;
    if (!(t < t_out)) return 0;

    const int64_t sx = gx > 0.0 ? 1 : -1, sy = gy > 0.0 ? 1 : -1;
    int64_t bp = patch_of(fx0 + t * gx, gx, nx) >> sh, bq = patch_of(fy0 + t * gy, gy, ny) >> sh;
    const int64_t max_iter = 2 * (bx_max + by_max) + 8;
    for (int64_t it = 0; it < max_iter; ++it) {
        /* where the ray leaves block (bp, bq): its edges hi(last patch) and lo(first patch) */
        const double ex = gx > 0.0 ? (double)(((bp + 1) << sh) - 1) : (double)((bp << sh) - 1);
        const double ey = gy > 0.0 ? (double)(((bq + 1) << sh) - 1) : (double)((bq << sh) - 1);
        const double txb = gx != 0.0 ? ((ex < -0.5 ? -0.5 : (ex > ex_hi ? ex_hi : ex)) - fx0) * igx : HUGE_VAL;
        const double tyb = gy != 0.0 ? ((ey < -0.5 ? -0.5 : (ey > ey_hi ? ey_hi : ey)) - fy0) * igy : HUGE_VAL;
        double tb = txb < tyb ? txb : tyb;
        tb = tb < t_out ? tb : t_out;
        const double zmax = dz > 0.0 ? oz + tb * dz : oz + t * dz;
        if (!(zmax < s->block_min[bp * s->nby + bq])) {
            /* the ray may reach the seabed in this block: visit its patches, in order */
            const int64_t p_first = bp << sh, p_last = p_first + bs - 1 < nx ? p_first + bs - 1 : nx;
            const int64_t q_first = bq << sh, q_last = q_first + bs - 1 < ny ? q_first + bs - 1 : ny;
            int64_t p = patch_of(fx0 + t * gx, gx, nx), q = patch_of(fy0 + t * gy, gy, ny);
            p = p < p_first ? p_first : (p > p_last ? p_last : p);
            q = q < q_first ? q_first : (q > q_last ? q_last : q);
            for (;;) {
                const double tx = gx > 0.0   ? (hi_edge(p, nx) - fx0) * igx
                                  : gx < 0.0 ? (lo_edge(p) - fx0) * igx
                                             : HUGE_VAL;
                const double ty = gy > 0.0   ? (hi_edge(q, ny) - fy0) * igy
                                  : gy < 0.0 ? (lo_edge(q) - fy0) * igy
                                             : HUGE_VAL;
                double te = tx < ty ? tx : ty;
                te = te < t_out ? te : t_out;
                if (patch_hit(s, p, q, fx0, fy0, gx, gy, oz, dz, t, te, t_hit)) return *t_hit < t_lim;
                if (te >= t_out) return 0;
                t = te;
                if (tx <= ty) {
                    p += sx;
                    if (p < p_first || p > p_last) break;
                } else {
                    q += sy;
                    if (q < q_first || q > q_last) break;
                }
            }
        } else {
            /* the ray stays above the block's shallowest sample: pass over the block */
            if (tb >= t_out) return 0;
            t = tb;
        }
        const int step_x = txb <= tyb;
        bp += step_x ? sx : 0;
        bq += step_x ? 0 : sy;
        if (bp < 0 || bp > bx_max || bq < 0 || bq > by_max) return 0;
    }
    return 0; /* not reached for finite inputs */
}

/*
 * Cast all beams of every vehicle of environments [b0, b1) (the caller splits work across threads
 * by environments). Arrays are C-contiguous:
 *   poses (B, N, 6) [x, y, z, phi, theta, psi]; radii (N) or NULL (vehicles not detected);
 *   active (B, N) uint8 or NULL (all present; an inactive vehicle is not detected, it still
 *   senses); ranges (B, N, K) out; hit_id (B, N, K) out or NULL: -1 no return, -2 seabed, j >= 0
 *   vehicle j; hit_xyz (B, N, K, 3) out or NULL: where each ray ended.
 * Returns 0, or -1 when N exceeds MAXC vehicles.
 */
int hptv_sonar3d_cast(const hptv_sonar3d_t *sonar, int64_t b0, int64_t b1, int64_t n_agents, const double *poses,
                      const double *radii, const uint8_t *active, double *ranges, int32_t *hit_id,
                      double *hit_xyz)
{
    const int64_t n_beams = sonar->n_beams;
    const double *beams = sonar->beams;
    const double max_range = sonar->max_range, min_range = sonar->min_range;
    const double ires = 1.0 / sonar->res;
    const seabed_t sb = {sonar->depth, sonar->block_min, sonar->nx, sonar->ny, sonar->block_shift, sonar->nby};
    enum { MAXC = 256 };
    double cx[MAXC], cy[MAXC], cz[MAXC], cr2[MAXC];
    int32_t cid[MAXC];
    if (radii != NULL && n_agents > MAXC) return -1;
    for (int64_t b = b0; b < b1; ++b) {
        const double *pb = poses + b * n_agents * 6;
        for (int64_t a = 0; a < n_agents; ++a) {
            const double *pa = pb + a * 6;
            const double ox = pa[0], oy = pa[1], oz = pa[2];
            const double cf = cos(pa[3]), sf = sin(pa[3]);
            const double ct = cos(pa[4]), st = sin(pa[4]);
            const double cp = cos(pa[5]), sp = sin(pa[5]);
            /* R = Rz(psi) Ry(theta) Rx(phi), Fossen (2021) Eq. 2.18 */
            const double r00 = cp * ct, r01 = -sp * cf + cp * st * sf, r02 = sp * sf + cp * cf * st;
            const double r10 = sp * ct, r11 = cp * cf + sf * st * sp, r12 = -cp * sf + st * sp * cf;
            const double r20 = -st, r21 = ct * sf, r22 = ct * cf;
            const double fx0 = (ox - sonar->x0) * ires, fy0 = (oy - sonar->y0) * ires;
            const int64_t ray0 = (b * n_agents + a) * n_beams;
            int nc = 0; /* other vehicles that any beam could reach */
            if (radii != NULL) {
                for (int64_t o = 0; o < n_agents; ++o) {
                    if (o == a || (active != NULL && !active[b * n_agents + o])) continue;
                    const double *po = pb + o * 6;
                    const double fx = ox - po[0], fy = oy - po[1], fz = oz - po[2];
                    const double reach = max_range + radii[o];
                    if (fx * fx + fy * fy + fz * fz > reach * reach) continue;
                    cx[nc] = po[0];
                    cy[nc] = po[1];
                    cz[nc] = po[2];
                    cr2[nc] = radii[o] * radii[o];
                    cid[nc] = (int32_t)o;
                    ++nc;
                }
            }
            for (int64_t k = 0; k < n_beams; ++k) {
                const double bx = beams[k * 3 + 0], by = beams[k * 3 + 1], bz = beams[k * 3 + 2];
                const double dx = r00 * bx + r01 * by + r02 * bz;
                const double dy = r10 * bx + r11 * by + r12 * bz;
                const double dz = r20 * bx + r21 * by + r22 * bz;
                /* where the ray ends with no return: max_range, or the sea surface */
                double t_lim = max_range;
                if (oz < 0.0) {
                    t_lim = 0.0;
                } else if (dz < 0.0) {
                    const double ts = -oz / dz;
                    if (ts < t_lim) t_lim = ts;
                }
                int32_t id = -1;
                for (int c = 0; c < nc; ++c) {
                    const double fx = ox - cx[c], fy = oy - cy[c], fz = oz - cz[c];
                    const double bq = fx * dx + fy * dy + fz * dz;
                    const double cq = (fx * fx + fy * fy + fz * fz) - cr2[c];
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
                    if (tc < t_lim) {
                        t_lim = tc;
                        id = cid[c];
                    }
                }
                double t_end = t_lim;
                /* the seabed, unless the ray stays above the map's shallowest sample throughout */
                if (sb.depth != NULL && !((oz > oz + t_lim * dz ? oz : oz + t_lim * dz) < sonar->shallowest)) {
                    double th;
                    if (cast_seabed(&sb, fx0, fy0, oz, dx * ires, dy * ires, dz, t_lim, &th)) {
                        t_end = th;
                        id = -2;
                    }
                }
                const double r = id == -1 ? max_range : (t_end > min_range ? t_end : min_range);
                ranges[ray0 + k] = r;
                if (hit_id != NULL) hit_id[ray0 + k] = id;
                if (hit_xyz != NULL) {
                    hit_xyz[(ray0 + k) * 3 + 0] = ox + t_end * dx;
                    hit_xyz[(ray0 + k) * 3 + 1] = oy + t_end * dy;
                    hit_xyz[(ray0 + k) * 3 + 2] = oz + t_end * dz;
                }
            }
        }
    }
    return 0;
}
