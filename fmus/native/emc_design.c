/* emcosim's native controllers: the linear algebra of the design's conditions (emc_design.h). */
#include <math.h>
#include <string.h>

#include "emc_design.h"

#define EMC_DN EMC_DESIGN_MAX_ORDER
#define EMC_JACOBI_SWEEPS 64                /* cyclic Jacobi: converges in < 10 sweeps for n <= 20; the bound */
#define EMC_ROOT_ITERATIONS 500             /* Durand-Kerner: the bound on its iterations */
#define EMC_EPS 2.220446049250313e-16       /* DBL_EPSILON */

/* the smallest eigenvalue of the symmetric part of the order-n matrix A (row-major), by cyclic Jacobi rotations */
double emc_min_eig(const double *A, int n)
{
    double a[EMC_DN * EMC_DN], lowest;
    int sweep, p, q, k;
    if (n < 1 || n > EMC_DN) return NAN;
    for (p = 0; p < n; p++)
        for (q = 0; q < n; q++) a[p * n + q] = 0.5 * (A[p * n + q] + A[q * n + p]);
    for (sweep = 0; sweep < EMC_JACOBI_SWEEPS; sweep++) {
        double off = 0.0, diagonal = 0.0;
        for (p = 0; p < n; p++)
            for (q = 0; q < n; q++) {
                if (p == q) diagonal += a[p * n + p] * a[p * n + p];
                else off += a[p * n + q] * a[p * n + q];
            }
        if (!(off > 1e-34 * diagonal)) break;          /* off-diagonal below rounding (or not finite) */
        for (p = 0; p < n - 1; p++)
            for (q = p + 1; q < n; q++) {
                double apq = a[p * n + q], theta, t, cs, sn;
                if (apq == 0.0) continue;
                theta = (a[q * n + q] - a[p * n + p]) / (2.0 * apq);
                t = fabs(theta) > 1e150 ? 0.5 / theta
                    : (theta >= 0.0 ? 1.0 : -1.0) / (fabs(theta) + sqrt(theta * theta + 1.0));
                cs = 1.0 / sqrt(t * t + 1.0);
                sn = t * cs;
                for (k = 0; k < n; k++) {               /* A J */
                    double akp = a[k * n + p], akq = a[k * n + q];
                    a[k * n + p] = cs * akp - sn * akq;
                    a[k * n + q] = sn * akp + cs * akq;
                }
                for (k = 0; k < n; k++) {               /* J^T (A J) */
                    double apk = a[p * n + k], aqk = a[q * n + k];
                    a[p * n + k] = cs * apk - sn * aqk;
                    a[q * n + k] = sn * apk + cs * aqk;
                }
            }
    }
    lowest = a[0];
    for (p = 1; p < n; p++)
        if (!(a[p * n + p] >= lowest)) lowest = a[p * n + p];
    return lowest;
}

/* A > 0 decided in the matrix's own scale, as components.certificates.definiteness: the smallest eigenvalue of
   D^-1/2 S D^-1/2 (S the symmetric part, D = diag S, a congruence: Sylvester's law of inertia) against the rounding
   8 n eps max(1, max |entry|) of its unit-diagonal entries; a diagonal entry <= 0 fails (number: the smallest) */
int emc_scaled_definiteness(const double *A, int n, double *number, const char **note)
{
    double B[EMC_DN * EMC_DN], r[EMC_DN], biggest = 1.0, rounding, lowest = INFINITY;
    int i, j;
    *note = "";
    if (n < 1 || n > EMC_DN) {
        *number = NAN;
        *note = "the matrix is larger than EMC_DESIGN_MAX_ORDER";
        return EMC_INCONCLUSIVE;
    }
    for (i = 0; i < n * n; i++)
        if (!isfinite(A[i])) {
            *number = NAN;
            *note = "the matrix has entries that are not finite";
            return EMC_INCONCLUSIVE;
        }
    for (i = 0; i < n; i++)
        if (A[i * n + i] < lowest) lowest = A[i * n + i];
    if (lowest <= 0.0) {
        *number = lowest;
        *note = "a diagonal entry is <= 0";
        return EMC_FAILS;
    }
    for (i = 0; i < n; i++) r[i] = 1.0 / sqrt(A[i * n + i]);
    for (i = 0; i < n; i++)
        for (j = 0; j < n; j++) {
            B[i * n + j] = 0.5 * (A[i * n + j] + A[j * n + i]) * (r[i] * r[j]);
            if (fabs(B[i * n + j]) > biggest) biggest = fabs(B[i * n + j]);
        }
    *number = emc_min_eig(B, n);
    rounding = 8.0 * n * EMC_EPS * biggest;
    if (*number > rounding) return EMC_HOLDS;
    if (*number < -rounding) return EMC_FAILS;
    *note = "its smallest eigenvalue is below the rounding of its entries";
    return EMC_INCONCLUSIVE;
}

/* the characteristic polynomial det(lambda I - A) = sum_i c[i] lambda^i (c[n] = 1) of the order-n matrix A,
   by Faddeev-LeVerrier: M_k = A M_(k-1) + c[n-k+1] I, c[n-k] = -tr(A M_k) / k */
void emc_characteristic_polynomial(const double *A, int n, double *c)
{
    double M[EMC_DN * EMC_DN], AM[EMC_DN * EMC_DN];
    int i, j, l, k;
    if (n < 1 || n > EMC_DN) return;
    memset(M, 0, sizeof M);
    c[n] = 1.0;
    for (k = 1; k <= n; k++) {
        double trace = 0.0;
        for (i = 0; i < n; i++)                        /* M = A M + c[n-k+1] I */
            for (j = 0; j < n; j++) {
                double sum = 0.0;
                for (l = 0; l < n; l++) sum += A[i * n + l] * M[l * n + j];
                AM[i * n + j] = sum + (i == j ? c[n - k + 1] : 0.0);
            }
        memcpy(M, AM, sizeof M);
        for (i = 0; i < n; i++)
            for (l = 0; l < n; l++) trace += A[i * n + l] * M[l * n + i];
        c[n - k] = -trace / k;
    }
}

/* Routh-Hurwitz: every root of sum_i c[i] lambda^i (degree n, c[n] = 1) has a negative real part iff every
   coefficient and every entry of the Routh array's first column is > 0 (no eigenvalue is computed) */
static int hurwitz(const double *c, int n)
{
    double r0[EMC_DN / 2 + 2] = {0.0}, r1[EMC_DN / 2 + 2] = {0.0}, r2[EMC_DN / 2 + 2] = {0.0};
    int w = n / 2 + 1, i, k;
    for (i = 0; i <= n; i++)
        if (!(c[i] > 0.0)) return 0;
    for (i = 0; i <= w; i++) {
        r0[i] = n - 2 * i >= 0 ? c[n - 2 * i] : 0.0;
        r1[i] = n - 1 - 2 * i >= 0 ? c[n - 1 - 2 * i] : 0.0;
    }
    for (k = 2; k <= n; k++) {
        if (!(r1[0] > 0.0)) return 0;
        for (i = 0; i < w; i++) r2[i] = (r1[0] * r0[i + 1] - r0[0] * r1[i + 1]) / r1[0];
        r2[w] = 0.0;
        memcpy(r0, r1, sizeof r0);
        memcpy(r1, r2, sizeof r1);
    }
    return r1[0] > 0.0;
}

/* A Hurwitz by more than its rounding: A + s I Hurwitz (every eigenvalue's real part < -s) by Routh-Hurwitz, with
   s = 4 n eps max(1, max |A_ij|), the size of the rounding of an eigenvalue; a real part within s of the
   imaginary axis (as numpy's eigenvalues of the twin place it: at 0 or at rounding noise) is not Hurwitz */
int emc_hurwitz_beyond_rounding(const double *A, int n, double *shift)
{
    double B[EMC_DN * EMC_DN], c[EMC_DN + 1], biggest = 1.0;
    int i;
    *shift = 0.0;
    if (n < 1 || n > EMC_DN) return 0;
    for (i = 0; i < n * n; i++) {
        if (!isfinite(A[i])) return 0;
        if (fabs(A[i]) > biggest) biggest = fabs(A[i]);
    }
    *shift = 4.0 * n * EMC_EPS * biggest;
    memcpy(B, A, (size_t)(n * n) * sizeof *B);
    for (i = 0; i < n; i++) B[i * n + i] += *shift;
    emc_characteristic_polynomial(B, n, c);
    return hurwitz(c, n);
}

/* the d-th derivative of sum_i c[i] z^i (degree n) and its derivative at the complex z = (zr, zi), by Horner */
static void derivative_at(const double *c, int n, int d, double zr, double zi, double *f, double *g)
{
    double a, fr = 0.0, fi = 0.0, gr = 0.0, gi = 0.0, t;
    int i, j;
    for (i = n; i >= d; i--) {
        for (a = c[i], j = i; j > i - d; j--) a *= j;               /* the coefficient of z^(i-d): c[i] i!/(i-d)! */
        t = gr * zr - gi * zi + fr;                                  /* g = g z + f, f = f z + a */
        gi = gr * zi + gi * zr + fi;
        gr = t;
        t = fr * zr - fi * zi + a;
        fi = fr * zi + fi * zr;
        fr = t;
    }
    f[0] = fr, f[1] = fi, g[0] = gr, g[1] = gi;
}

/* the largest real part of a root of the monic polynomial sum_i c[i] lambda^i (degree n), by Durand-Kerner's
   simultaneous iteration from a circle that holds every root (Fujiwara's bound); for the message only. A root of
   multiplicity k comes out of it only to ~eps^(1/k) of the roots' size (1.9e-9 for the double +-i of the F_d of a
   plant with two undamped mechanical coordinates, R_m = 0): a cluster of k roots within EMC_CLUSTER of the size is
   one root of multiplicity k, a simple root of the (k-1)-th derivative, which Newton's method (at most
   EMC_POLISH steps from the cluster's mean) finds to rounding */
#define EMC_CLUSTER 1e-6
#define EMC_POLISH 16
double emc_spectral_abscissa(const double *c, int n)
{
    double re[EMC_DN] = {0.0}, im[EMC_DN] = {0.0}, radius = 0.0, largest = -INFINITY;
    int i, j, k, it;
    if (n < 1 || n > EMC_DN) return NAN;
    for (i = 0; i < n; i++) {                          /* Fujiwara's bound: 2 max_k |c[n-k]|^(1/k) */
        double r = 2.0 * pow(fabs(c[i]), 1.0 / (n - i));
        if (r > radius) radius = r;
    }
    if (!(radius > 0.0)) radius = 1.0;
    for (k = 0; k < n; k++) {
        re[k] = radius * cos(6.283185307179586 * k / n + 0.4);
        im[k] = radius * sin(6.283185307179586 * k / n + 0.4);
    }
    for (it = 0; it < EMC_ROOT_ITERATIONS; it++) {
        double change = 0.0, size = 0.0;
        for (k = 0; k < n; k++) {
            double pr = 1.0, pi = 0.0, qr = 1.0, qi = 0.0, t, d;
            for (i = n - 1; i >= 0; i--) {             /* p(z) by Horner */
                t = pr * re[k] - pi * im[k] + c[i];
                pi = pr * im[k] + pi * re[k];
                pr = t;
            }
            for (j = 0; j < n; j++) {                   /* prod_(j != k) (z_k - z_j) */
                double dr = re[k] - re[j], di = im[k] - im[j];
                if (j == k) continue;
                t = qr * dr - qi * di;
                qi = qr * di + qi * dr;
                qr = t;
            }
            d = qr * qr + qi * qi;
            if (!(d > 0.0)) continue;
            t = (pr * qr + pi * qi) / d;                /* p / q */
            d = (pi * qr - pr * qi) / d;
            re[k] -= t;
            im[k] -= d;
            change = fmax(change, hypot(t, d));
            size = fmax(size, hypot(re[k], im[k]));
        }
        if (!(change > 1e-15 * size)) break;
    }
    for (j = 0; j < n; j++) radius = j ? fmax(radius, hypot(re[j], im[j])) : hypot(re[j], im[j]);   /* the size */
    for (k = 0; k < n; k++) {
        double zr = 0.0, zi = 0.0, f[2], g[2], d, sr, si;
        int count = 0;
        for (j = 0; j < n; j++)
            if (hypot(re[j] - re[k], im[j] - im[k]) <= EMC_CLUSTER * radius) {
                zr += re[j];
                zi += im[j];
                count++;
            }
        if (count == 0) zr = re[k], zi = im[k], count = 1;     /* a root that is not finite: no cluster */
        else zr /= count, zi /= count;
        for (it = 0; count > 1 && it < EMC_POLISH; it++) {
            derivative_at(c, n, count - 1, zr, zi, f, g);
            d = g[0] * g[0] + g[1] * g[1];
            if (!(d > 0.0)) break;
            sr = (f[0] * g[0] + f[1] * g[1]) / d;                    /* f / g */
            si = (f[1] * g[0] - f[0] * g[1]) / d;
            zr -= sr, zi -= si;
            if (!(hypot(sr, si) > 4.0 * EMC_EPS * hypot(zr, zi))) break;
        }
        if (!(hypot(zr - re[k], zi - im[k]) <= EMC_CLUSTER * radius)) zr = re[k];  /* Newton left the cluster */
        if (zr > largest) largest = zr;
    }
    return largest;
}
