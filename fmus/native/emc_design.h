/* emcosim's native controllers: the linear algebra of the design's conditions (components.certificates.design_checks),
 * without eigenvalue libraries: the smallest eigenvalue of a symmetric part (cyclic Jacobi), the unit-diagonal scaled
 * definiteness test of certificates.definiteness, Routh-Hurwitz (Faddeev-LeVerrier's characteristic polynomial) and,
 * for a message only, the largest real part of an eigenvalue (Durand-Kerner). Matrices are row-major, of order
 * n <= EMC_DESIGN_MAX_ORDER; every loop is bounded and nothing is allocated (docs/native-fmus.md).
 * tests/test_native_strict.py checks them against numpy at random matrices of orders 1 to 16.
 */
#ifndef EMC_DESIGN_H
#define EMC_DESIGN_H

#define EMC_DESIGN_MAX_ORDER 16            /* components.c_codegen.design_checks_available: n = 2 n_m + n_e <= 16 */

enum { EMC_HOLDS, EMC_FAILS, EMC_INCONCLUSIVE };

/* the smallest eigenvalue of the symmetric part of A */
double emc_min_eig(const double *A, int n);
/* A > 0 as certificates.definiteness decides it: EMC_HOLDS, EMC_FAILS or EMC_INCONCLUSIVE, with its number (the
   smallest eigenvalue of the unit-diagonal scaling, or the smallest diagonal entry when one is <= 0) and its note */
int emc_scaled_definiteness(const double *A, int n, double *number, const char **note);
/* det(lambda I - A) = sum_i c[i] lambda^i, c[n] = 1 (c untouched for an order outside 1..EMC_DESIGN_MAX_ORDER) */
void emc_characteristic_polynomial(const double *A, int n, double *c);
/* 1 when every eigenvalue of A has a real part < -shift, shift = 4 n eps max(1, max |A_ij|) (set in *shift) */
int emc_hurwitz_beyond_rounding(const double *A, int n, double *shift);
/* the largest real part of a root of the monic polynomial sum_i c[i] lambda^i of degree n */
double emc_spectral_abscissa(const double *c, int n);

#endif
