/* The linear algebra of emc_design.c for tests/test_native_strict.py: reads matrices from stdin, each as its order
 * n and n * n numbers (row-major), and prints per matrix one line with %.17g:
 *     min_eig  scaled_verdict  scaled_number  hurwitz  shift  spectral_abscissa
 * (scaled_verdict: 0 holds, 1 fails, 2 inconclusive; hurwitz: emc_hurwitz_beyond_rounding). */
#include <stdio.h>

#include "emc_design.h"

int main(void)
{
    double A[EMC_DESIGN_MAX_ORDER * EMC_DESIGN_MAX_ORDER], c[EMC_DESIGN_MAX_ORDER + 1], number, shift;
    const char *note;
    int n, i, verdict, hurwitz;
    while (scanf("%d", &n) == 1) {
        if (n < 1 || n > EMC_DESIGN_MAX_ORDER) return 2;
        for (i = 0; i < n * n; i++)
            if (scanf("%lf", &A[i]) != 1) return 3;
        verdict = emc_scaled_definiteness(A, n, &number, &note);
        hurwitz = emc_hurwitz_beyond_rounding(A, n, &shift);
        emc_characteristic_polynomial(A, n, c);
        printf("%.17g %d %.17g %d %.17g %.17g\n", emc_min_eig(A, n), verdict, number, hurwitz, shift,
               emc_spectral_abscissa(c, n));
    }
    return 0;
}
