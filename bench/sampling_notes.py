"""The prose of the sampling reports (bench.sampling): what the criteria show and
why our numbers differ from the thesis."""

from __future__ import annotations

DISCUSSION = """\
### Why our numbers differ from the thesis

* **Scenes.** The thesis's bird's nest, grass, city and tree models are not
  available; ours are procedural stand-ins with the same triangle budgets
  (`scenes/builtin`) but a different depth complexity. All metrics depend on
  how much hidden, front-facing geometry lies behind what V0..V2 see, so
  per-cell gaps of tens of points are expected; the orderings are what can be
  compared (section "The thesis's claims, checked").
* **Ground.** The nest and the tree stand on modest ground discs (1.4 × their
  footprint); grass and city grounds are the patch and the street grid the
  content covers. (Earlier runs used 1.5 m / 12 m ground quads around the
  nest / tree: the plane filled the image corners with ground that NR images
  mostly drop as redundant or keep as non-occluded, and lowered the NR
  occluded fractions; the counts of useful occluded samples barely changed.)
* **Tiny triangles and resolution.** The nest's twigs and the tree's leaves
  are a few pixels or less at 512²: pixel redundancy (same triangle id at the
  reprojected texel) then misses much of the true redundancy, so conventional
  redundancy is lower, NR images keep visible samples that only differ by
  triangle, and pixel-definition availability is low. The sweep (Figs 13-15)
  shows pixel-definition values converging toward the visibility-definition
  ones as the resolution grows, as §2.3.3 states; it also shows NR overtaking
  the conventional set in pixel-definition availability only from 512² up.
* **Rig.** Fig. 8 gives no numbers: we use `scenes.rig.fig8_rig` (eyes 20° off
  a common axis at elevation 25°, fov 45°) framed on the scene without its
  ground: the content box's bounding sphere just fits the narrowest view of the
  rig (`scenes.rig.fit_distance`, 1.39 × the content diagonal), so every
  reference, peeling and intermediate view holds the whole content. Clip
  planes are fitted to the whole scene. Only the tree's ground disc reaches
  past the peeling view: 0.5 % of the tree's intermediate-view samples lie
  outside the peeling camera's frustum (inside all of V0..V2's), which lowers
  peeling's available fraction on the tree by at most that much (measured at
  128², 20 views; nest, grass, city: 0 %). A wider spread makes V1/V2 less
  redundant and NR images less deep.
* **Views.** Fewer intermediate views than the thesis's 1000 lower the useful
  fraction slightly (a sample needed by a rare view can be missed) and raise
  the minimum available fraction.
* **Depth peeling.** Its first layer comes from the centroid, itself an
  intermediate view, so its occluded samples are almost all useful; its deeper
  layers are complete images of the hidden layers, so in absolute counts
  peeling often collects more occluded samples than our sparse NR images.
  The thesis's layer 1 is nearly useless on the nest, grass and city (2, 4,
  7 % of its occluded samples, Table 2) where ours is not (80, 99, 46 % at
  512², 200 views): peeling *without* back-face culling gives 6 % on our
  closed nest and city models, its layer 1 being their inside
  (`bench/results/peeling_sides.md`, `python -m bench.peeling_sides`). The
  thesis's Table 5 layer-1 and layer-2 shares fit our culled peeling better
  (mean gap 20 against 33 points), so no single peeling matches both
  tables; we keep the culled peeling the issue asks for (it has more useful
  occluded samples on every scene). Against the two-sided peeling, NR's
  useful occluded samples under the issue's reading still trail on 4 / 4
  scenes (pixel) and 2 / 4 (visibility).
* **Definitions.** Where §2.3.2 is not precise we chose (see
  `reference/sampling_metrics.py`): occluded is computed under both readings
  (the issue's: not captured by any of the n conventional images, fraction of
  the image's samples; the thesis's literal item 2: NR I_i against C_0..C_{i-1},
  fraction of C_i's samples); visibility-definition availability compares with the
  *layer* of what each image stores within one texel. Background pixels are
  not samples. GL samples tested with Embree are not exactly consistent at
  silhouettes: conventional images show ~1e-4 "occluded" samples and peeling
  layers ~0.5-1 % visibility-redundant ones (float32 positions on thin twigs
  and leaves, whose occlusion ray grazes the occluder's edge).
* **Timing.** Table 7 in the thesis is a GTX 570; ours is Mesa llvmpipe on a
  shared 2-core CPU, so absolute times are ~100× larger and only the ratios are
  comparable. On llvmpipe the NR pass's extra cost (one reprojection and
  texture fetch per previous image per fragment) is small against rasterising
  and shading 50-113k triangles on the CPU, so NR/conventional is lower than
  the thesis's 1.8-3.0; NR/peeling is close to the thesis's (≈1). The thesis
  blames its geometry shader for the tree's cost; the geometry-shader variant
  rows measure that set-up here. The machine is shared: with 5 rounds single
  ratios moved by ±20 % between runs, hence the interleaved rounds stated
  under "What was run" (compare the two variants of a scene).
"""


CRITERIA_NOTES = """\
### What the criteria show, and why (measured)

* **The issue's target configuration, 1024² with 1000 intermediate views**
  (`sampling_1024_1000v/`: 105 min on this 2-core machine, 18-43 min per
  scene, with the Embree reference caster split across threads), gives the
  same verdicts as the 1024²/60-view run on every scene and definition: (a)
  4 / 4; (b) with visibility 4 / 4, with pixel 1 / 4 (nest; NR trails the
  conventional set on average by 0.21 / 0.72 / 0.86 points on grass / city /
  tree, and on the minimum by 0.57 / 0.61 points on grass / tree); (c) with the
  thesis's reading 4 / 4 under both definitions (NR 1.22-2.47× peeling's
  useful occluded samples), with the issue's reading pixel 0 / 4, visibility
  1 / 4 (city). From 60 to 1000 views the averages moved by at most 0.3
  points; the minima fell by up to 0.3 points for NR and the conventional
  set and by 0.3-2.2 points for peeling (views near the rig's corners see
  past the centroid's layers); useful counts grew by 1-28 % (a sample needed
  only by a rare view), for NR and peeling alike.
* **(a) holds.** The visibility NR sets (Embree) have no visibility-redundant
  sample. The GL pixel NR sets show 0-11 pixel-redundant samples out of
  1e5-3e5 when the reference re-tests them, and every one is a texel-edge
  tie: its projection lies within 1e-4 texel of a texel edge (measured on nest
  and grass at 1024²), where GL's float32 Alg. 3 and the reference's float64
  projection fall on neighbouring texels; at 2048² (12 views) one tree
  sample in 6e5 lies 3.4e-3 texel from the edge (not counted as a tie: the
  float32 error in texel units grows with the resolution); the same sets
  rendered by Embree in float64 (`reference.visibility.non_redundant_reference`,
  `bench/results/tessellation.md`) have none. (Until this run the visibility NR
  sets also showed 0-1 such sample: `non_redundant_visibility` tested the
  float64 hit point but stored it as float32, and an occlusion ray grazing an
  edge could answer differently for the two; it now tests the stored point.)
* **(b) holds with the visibility definition on all four scenes** at 512² and
  1024² (NR ahead of conventional by 1.4-6.5 points and of peeling by 1.0-1.7
  points on average; on the minimum by 2.8-8.0 and 2.3-5.5 points). **With
  the pixel definition NR stays ahead of peeling but falls 0.15-1.5 points
  below the conventional set**
  on grass, city and tree (and on nest at 512²; at 1024² nest holds). The
  mechanism, measured on grass and nest at 512² (10 views): per view NR loses
  3.4 % (grass) / 2.4 % (nest) of the samples the conventional set makes
  available and gains 2.4 % / 2.1 %; 100 % of the lost samples are on a
  triangle that C1 or C2 holds at their texel and that NR dropped there as
  pixel-redundant with an earlier image, while the frame sample's own
  projection into that earlier image lands on a texel of another triangle
  (silhouettes of thin blades, twigs and leaves, and building edges). Alg. 3
  forces this, whatever the implementation: it keeps or drops a whole texel by
  its centre, and in an 8×8 case counted by hand (offset scene,
  `tests/test_sampling_metrics.py`) the NR set, with no redundant sample, makes
  6 of a frame's 8 columns available where the conventional set makes all 8
  (visibility definition: 8 and 8). It is
  the pixel definition's texel granularity: the gap shrinks from 512² to
  1024² (grass 0.98 → 0.15, city 1.09 → 0.54, tree 1.46 → 0.84 points; nest
  −0.32 → +0.86) as pixel redundancy converges to visibility redundancy, and
  at 2048² (12 views, `sampling_2048/`) (b) holds with the pixel definition on
  nest, grass and city (NR ahead of conventional by 0.3-1.9 points) and the
  tree ties (average −0.01 point, minimum +0.2). The gap belongs to Alg. 3,
  not to our GL pass, and it follows the triangles' size against the texel
  (`bench/results/tessellation.md`, `python -m bench.tessellation`, 1024², 60
  views): the same NR sets rendered by Embree
  (`reference.visibility.non_redundant_reference`) give the GL sets'
  availability to ≤ 0.05 point; splitting every triangle into 4 and 16, with
  the surfaces unchanged (visibility metrics move ≤ 0.14 point), takes (b)
  with the pixel definition from 1 / 4 scenes to 0 / 4, and NR's average
  lead over the conventional set from −0.84 … +0.86 points (as tessellated)
  to −2.09 … −0.95 (16 triangles each). Finer triangles do not reproduce the
  thesis's tree row either (its conventional set loses 30 points from Table 6
  to Table 4, yet NR is 4 points ahead): our tree's conventional set loses
  5-15 points that way (1× to 16×) and NR trails more the finer it gets.
* **(c) holds with the thesis's reading of "occluded" on 4 / 4 scenes, under
  both redundancy definitions, at 512² and at 1024² (NR ahead of peeling by
  1.16-2.6× in useful occluded samples); with the issue's reading it fails
  (pixel 0 / 4, visibility 1 / 4, city).** The two readings
  (`reference/sampling_metrics.py`, both computed in every run): the issue
  summarises occluded samples as "not captured by the conventional images of
  V0..Vn-1"; §2.3.2 item 2 says, for an NR image from PPC_i, "not captured by
  the conventional images of PPC_j, j = 0..i-1", and for peeling "by any
  conventional image". We report both and judge (c) on the thesis's text,
  which is the spec, for three measured reasons: (1) the thesis's own tree
  row (conventional I1 23 % redundant, NR I1 84 % occluded) is impossible
  under the issue's reading, where NR I1's first-layer samples (≥ 77 % of
  C1's pixels) are captured by C1; (2) its NR cells are reproduced far better
  under the literal reading, with percentages of C_i's samples: mean gap over
  the NR occluded/useful cells 29.0 → 18.9 points (pixel, 512²), 26.7 → 17.9
  (pixel, 1024²), 15.4 → 14.0 and 15.0 → 13.7 (visibility), e.g. nest NR I1
  53 % (91 %) against the thesis's 62 % (89 %) at 1024²; (3) under the issue's
  reading, an NR image's first-layer samples, seen from V_i and thus needed
  by the views near V_i, never count, while peeling's layer L0 counts in
  full although it is itself a conventional image of an intermediate view.
  Why the issue's reading goes against NR on our scenes (measured, per-image
  table above): *L0 is an intermediate view*, so its occluded samples are
  ~100 % useful, and with the pixel definition it is inflated by reprojection
  misses on sub-pixel triangles (L0 has 2.2-4.4× more occluded samples under
  the pixel than the visibility definition on nest, tree and grass);
  *our peeling layers 1-2 are far more useful than the thesis's* (useful
  share of L1's occluded samples 80 / 99 / 46 / 75 % on nest, grass, city,
  tree, pixel, 512², against 2 / 4 / 7 / 98 %): our occluders (twigs 4-10 mm,
  blades, leaves) are thin against the rig's eye baseline; and *NR images
  spend most samples on first-layer surfaces* V0 (or V0, V1) does not see.
  Ground, framing and borders are not the cause (variant without ground: < 1 %
  change; every view holds the content). The rig's spread, which Fig. 8 does
  not give, moves the issue-reading verdict but does not rescue it
  (`bench/results/rig_spread.md`, `python -m bench.rig_spread`, spreads
  5-30°, 512², 100 views): with the pixel definition (c) holds on 0 / 4 scenes
  at every spread; with the visibility definition on 3 / 4 at 5°, 2 / 4 at
  10-15°, 1 / 4 at 20° and 0 / 4 at 30°; with the thesis's reading on 4 / 4 at
  5-20°. (b) with the pixel definition fails at 512² at every spread. The
  thesis's conventional redundancy does not pin the spread down (mean gap
  12.6-15.1 points over the spreads, visibility; 16.2-22.6, pixel), so we keep
  20° rather than pick the value that favours NR.
* **(d) holds**: NR/conventional 1.16-1.32 and NR/peeling 0.91-1.07 at 1024²
  with either triangle-id source (llvmpipe, 15 interleaved rounds; Table 7).
  With 5 rounds one reading (grass, geometry shader) came out at NR/peeling
  1.34: single ratios on this shared 2-core machine move by ±20 %.
"""
