/* The paper's sampled bang-bang controller, in encoder counts: the one decision the sketch makes each
 * loop, kept in its own header so the host test (tests/firmware) can compile exactly this code with gcc
 * and hold it against pipeline/model/loop.py's `next_dir` and `decide`, sample for sample.
 *
 * The model decides on theta = counts * 2 pi / counts_per_rev against controller.guard_rad; the sketch
 * decides on counts against guard_counts, the smallest count whose angle reaches guard_rad, i.e.
 * ceil(guard_rad * counts_per_rev / (2 pi)) (980 for the paper's 0.15 rev at 6533.12 counts/rev).
 * Then counts >= guard_counts exactly when theta >= guard_rad, and likewise at -guard. */
#ifndef PDR_CONTROLLER_H
#define PDR_CONTROLLER_H

#include <stdint.h>

/* Motor off (the lead-in), mode q1 (+V), mode q2 (-V): the `dir` column's values. */
#define PDR_DIR_OFF 0
#define PDR_DIR_Q1 1
#define PDR_DIR_Q2 (-1)

/* The sketch's rule (loop.py next_dir): reverse when the angle has reached the guard in the direction
 * of motion; hold the mode otherwise; from motor off, start in q1 unless a guard is already reached. */
static inline int8_t pdr_next_dir(int8_t dir, int32_t counts, int32_t guard_counts)
{
    if (dir >= 0 && counts >= guard_counts) return PDR_DIR_Q2;
    if (dir <= 0 && counts <= -guard_counts) return PDR_DIR_Q1;
    return dir != PDR_DIR_OFF ? dir : PDR_DIR_Q1;
}

/* The command after sample k (counted from 0; the caller may stop counting at lead_in_samples): motor
 * off during the lead-in, then loop.py's decide in closed loop: the first motor-on sample decides from
 * first_dir (the model's dir0), every later one from the command before it. */
static inline int8_t pdr_command(int8_t dir, uint32_t k, uint32_t lead_in_samples, int32_t counts,
                                 int32_t guard_counts, int8_t first_dir)
{
    if (k < lead_in_samples) return PDR_DIR_OFF;
    return pdr_next_dir(dir != PDR_DIR_OFF ? dir : first_dir, counts, guard_counts);
}

/* x4 quadrature decoding: the count step for (previous AB << 2 | current AB); 0 for no change and for
 * the impossible double transitions (a missed edge), which must not count. */
static const int8_t PDR_QUADRATURE_STEP[16] = {
    0, +1, -1, 0,
    -1, 0, 0, +1,
    +1, 0, 0, -1,
    0, -1, +1, 0,
};

#endif
