"""Lightmap seams: where a smooth surface crosses from one chart to another, and the stitch
post stage that closes them. No bpy.

A *seam* is a 3D edge shared by two triangles whose lightmap UVs differ on it and whose vertex
normals agree at both ends (a smooth edge cut by the unwrap); a hard edge (different normals)
or an edge with the same UVs on both sides is not one. Along a seam the two charts hold their
own texels, so the bilinear reads on the two sides of one 3D point differ: a visible line.

  geometry        `find_seams`: sample pairs along every seam (`Seams`: positions on both
                  sides, texel units), saved as the atlas's seams file
  reads           `bilinear`: the GPU's bilinear read (texel centres at i + ½, clamp to edge);
                  the lightmap read as the preview reads it (`sh_reader`, `hhd_reader`)
  metrics         `seam_metric`: how visible the seams are, read as the preview reads the
                  lightmap (radiance SH, or the encoded HHD/AHD images), against the
                  texel-to-texel step inside the charts
  stitching       `stitch`: least-squares seam stitching of the SH (Sylvan 2015, "Fixing texture
                  seams with linear least-squares"), a post stage: the texels the seam samples
                  read are moved so both sides read alike, each pulled towards its baked value
                  (covered texels firmly, gutter texels weakly, from their dilated value); one
                  sparse system, 27 right-hand sides, Jacobi-preconditioned CG (`solve`); the
                  result bounded to a plausible radiance (L0, I_z ≥ 0, within the range of the
                  texels it is tied to). Stitched gutter and buried texels are handed to the
                  encoder as sources of their own (`TexelData.extra_sources`), so dilation does
                  not overwrite them. Seams into a surface inside closed geometry (buried texels
                  left black) are hidden: neither measured nor stitched (`hidden_texels`,
                  `reads_hidden`).
  solve           the least squares and its conjugate gradients
  encoded_stitch  `stitch_encoded`: the same on an HHD/AHD atlas's encoded layers (I_z, w_a,
                  packed direction), after encoding: the encoding is not linear in the SH, so a
                  stitched SH seam reopens a little in the preview; this closes it as the preview
                  reads it.

Texel space (as `core.raster`): x = u · W, y = v · H; texel (i, j) covers [i, i+1] × [j, j+1],
its centre is (i + ½, j + ½); images are `(H, W, ...)` with rows bottom-up, row index floor(y).
Unlike ands/seamoptimizer, reads use exactly this convention (no half-texel offset), an edge
shorter than a texel still gets one sample (no division by its length: no NaN), and an edge
whose two sides share their UVs is not a seam.
"""
