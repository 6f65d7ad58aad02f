/* render plots: the bake's per-frame diagnostics (out/<shot>/bake/progress.jsonl) drawn as PNG charts
 * by gnuplot, so a shot's cost and health can be judged at a glance next to its images. */
#ifndef DR_RENDER_PLOTS_H
#define DR_RENDER_PLOTS_H

#include "core/core.h"

/* Turns a bake's progress.jsonl into PNG plots in out_dir (created if missing) with gnuplot:
 *   seconds_per_frame.png  (wall-clock seconds per phase vs frame, stacked, plus the frame total)
 *   solver_iterations.png  (every iteration count present vs frame; substeps too)
 *   volume_drift.png       (the liquid's volume as its particles carry it, "liquid_particle_volume", in % of
 *                           the first frame's, only when the lines have it: a shot with liquid)
 *   energy.png             (kinetic energy and any "energy" group, when present)
 *   momentum.png           (when a "momentum" group is present)
 * and returns the number of plots written in *written (0 when the lines hold nothing plottable).
 *
 * The plots are generic over the keys present: every key under "seconds" except "frame" is a phase
 * (drawn only when some frame spent time in it), a key absent from some lines leaves a gap (a phase
 * absent counts 0 s); an iteration count that is 0 in every frame is left out. Every series of a plot
 * has its own colour, from a fixed palette of 24. When several lines carry
 * the same frame (a resumed bake appends again) the last one wins. Plots that do not apply to this
 * bake are removed from out_dir so that none from an earlier bake is left next to the new ones.
 *
 * Each PNG is rendered to "<name>.png.tmp.<pid>" and renamed into place only after gnuplot
 * succeeded, so a failure leaves no partial PNG. The .dat, script and gnuplot log live in a private
 * temporary directory ($TMPDIR or /tmp) that is always removed; gnuplot's output goes to that log,
 * never to the terminal.
 *
 * Errors: gnuplot missing from PATH (checked first) or failing is DR_ERR_RUNTIME (the latter quoting
 * the end of its log); a missing or empty progress.jsonl, a malformed line or a line without an
 * integer "frame" is DR_ERR_INPUT naming the file (and line); unwritable out_dir or temporary files
 * DR_ERR_IO. Not thread safe with another call on the same out_dir. */
DR_NODISCARD DrStatus plots_write(const char *progress_path, const char *out_dir, int *written, DrError *err);

#endif
