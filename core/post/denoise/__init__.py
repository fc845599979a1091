"""The denoise post stage: Open Image Denoise's lightmap filter on an atlas's SH, chart by chart. No bpy.

Input and output are `encoding.TexelData` images (rows bottom-up): only the SH of baked texels
(covered, not buried) changes. Per atlas:

1. **Charts**: the 8-connected components of the covered texels (`layout.label_charts`). A chart is
   denoised only with its own texels: the other charts' texels and buried texels inside its
   rectangle are masked out and refilled from its own: next to the chart its texels mirrored
   through its border (`fill._mirror`, a CNN's reflect padding), farther a local mean of its texels
   (`fill._smooth_fill`; copying the nearest texel repeats its noise in streaks the filter keeps).
2. **Pages**: each chart's rectangle plus MARGIN texels goes into a page image (skyline packing,
   `layout.layout`). Every OIDN call has a fixed cost whatever the size, and real atlases hold thousands of
   charts a few texels wide, so charts share pages; a chart then sees its neighbours in the page
   2·MARGIN texels away at the closest. To keep that from bleeding light, a page only holds charts
   whose mean luminance lies within one BRIGHTNESS_BAND factor of each other, and each page has
   its own `inputScale` (OIDN's auto-exposure rule over its charts' texels; a chart is never
   split between pages, so no chart sees two exposures).
3. **Filter** (`oidn.Denoiser`, RTLightmap; `filtering`), per page: L0 and I_z (the irradiance along n_v, RGB: what
   the HHD file stores first, and the part of band 1 along n_v) as HDR colour, raised to
   HDR_POWER (a compressed range) and back; the rest of band 1
   (across n_v) and band 2 in luminance, in directional mode, divided by the *denoised*
   luminance L0 and by the band's bound (|c_k / c_0| ≤ √3 in band 1, ≤ √5 in band 2 for any
   radiance ≥ 0) times DIRECTIONAL_RANGE, then scaled back by each colour's denoised L0 (one
   direction for all colours, as HHD's highlight direction is). Dividing by the denoised L0 (a
   smooth image) keeps the ratio linear in the noisy coefficient. Five OIDN calls per page.
4. **Energy**: at a few samples per texel the noise is heavy-tailed and the filter takes rare
   bright samples for outliers, darkening (by several percent in rooms lit by small emitters).
   L0 and I_z are scaled per page so their sums over its chart texels are the traced sums (an
   unbiased estimate with little noise of its own): each page keeps the traced mean, though
   light can still move between the charts of one page.

5. **Noise clamp**: where the tracer measured each texel's noise (`TexelData.noise`, the
   standard error of its luminance L0 from the spread between passes; unknown before
   `stages.NOISE_PASSES` passes),
   no coefficient moves further from the traced value than NOISE_CLAMP standard errors (scaled
   to its colour). A filter also changes what is not noise: it bleeds light into contact
   shadows and blurs edges, and at high sample counts that is all it changes. The clamp lets it
   remove noise where there is noise and keeps converged texels (a black corner every pass
   agreed on) as traced, so a denoised bake converges to the same image as a raw one. On a chart
   of fewer than SMALL_CHART texels the bound shrinks with the square root of its texel count:
   the filter has few texels there to tell the signal from the noise, and smooths over the
   chart's shading instead; within EDGE_RINGS texels of a chart's edge it is EDGE_CLAMP times
   as wide: there the filter sees the chart on one side only, and a chart's edge is where
   geometry meets (a wall's corner, an object's contact shadow), the shading steepest
   (`noise_clamp._ChartNoise`).

Charts darker than BLACK (mean L0 luminance) are left as they are: nothing to denoise.

The modules: `pages` (`denoise_texels`: every page, whole or in horizontal bands), `layout`
(charts and their pages), `fill` (the masked texels around a chart), `filtering` (a page's
features through the filter and back to SH; the process's `Denoiser`s), `noise_clamp` (the
noise clamp), `oidn` (OIDN's C API).
"""
