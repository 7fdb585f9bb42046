/*
 * The Gauss-Markov error model of Eq. 3 applied to sonar ranges, fused into one pass.
 *
 * Part of hptvsim (Apache-2.0). For each of n entries, with normals z1 (bias drive) and z2
 * (white noise) drawn beforehand by numpy in that order:
 *     bias = phi * bias + w_std * z1                       (Eq. 3b, exact AR(1) step)
 *     s    = y + bias + noise_std * z2                     (Eq. 3a)
 *     out  = y < max_range ? clip(s, 0, max_range) : max_range   (no echo: nothing to err)
 * The same operations, in the same order, as GaussMarkov.step, GaussMarkov.apply and
 * Sonar.measure (hptvsim/sensors/errors.py, sonar.py), which the tests compare it with.
 */
#include <stdint.h>

void hptv_gm_ranges(int64_t n, const double *y, double *bias, const double *z, double phi, double w_std,
                    double noise_std, double max_range, int64_t step_bias, int64_t add_bias, int64_t add_noise,
                    double *out) {
    int64_t k;
    const double *z1 = z, *z2 = step_bias ? z + n : z;
    for (k = 0; k < n; k++) {
        double s;
        if (step_bias) {
            double b = bias[k] * phi;
            b += w_std * z1[k];
            bias[k] = b;
        }
        s = y[k] + 0.0;
        if (add_bias) s += bias[k];
        if (add_noise) s += noise_std * z2[k];
        if (y[k] < max_range) {
            out[k] = s < 0.0 ? 0.0 : (s > max_range ? max_range : s);
        } else {
            out[k] = max_range;
        }
    }
}
