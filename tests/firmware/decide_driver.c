/* The host test's driver of firmware/pdr_logger/pdr_controller.h: the sketch's per-sample calls over a
 * whole run at once, so ctypes crosses into C once per run. */
#include "pdr_controller.h"

/* The commands the sketch decides on a run of encoder counts (its loop: pdr_command, then count on). */
void pdr_commands(const int32_t *counts, int32_t n, uint32_t lead_in_samples, int32_t guard_counts,
                  int8_t first_dir, int8_t *dirs)
{
    int8_t dir = PDR_DIR_OFF;
    uint32_t samples = 0;
    for (int32_t k = 0; k < n; k++) {
        dir = pdr_command(dir, samples, lead_in_samples, counts[k], guard_counts, first_dir);
        if (samples < lead_in_samples) samples++;
        dirs[k] = dir;
    }
}

/* The count the sketch's interrupts reach over a run of channel states (A << 1 | B), from the first. */
int32_t pdr_decode(const uint8_t *ab, int32_t n)
{
    int32_t count = 0;
    for (int32_t k = 1; k < n; k++) count += PDR_QUADRATURE_STEP[(ab[k - 1] << 2) | ab[k]];
    return count;
}
