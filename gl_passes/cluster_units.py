"""The image, storage-buffer and texture units of the cluster-reflection shaders
(technique 3, thesis Ch. 4: cluster_*.comp, cluster_depth.vert/frag,
cluster_peel.frag, reflect_*.comp), in one table (gl_passes.bindings.Units).

One table for the whole family, because its passes hand resources to each other
through their bindings: the G-buffer textures and the mesh/remap/frame storage
buffers bound for the cluster cameras' extent passes (§4.4) stay bound for the
intersection (Alg. 7). Every shader of the family is compiled with
`UNITS.defines()` and declares `layout(binding = UNIT_<name>)`; the Python side
binds through `UNITS.bind_*` only."""

from __future__ import annotations

from gl_passes.bindings import Units

UNITS = Units(
    # images (write targets of compute passes), grouped by the shaders that bind them
    # together (cluster_assign/accumulate, reflect_trace, cluster_block_depth)
    images=(("u_bin_image", "u_mnormal_image"), ("u_out",), ("u_block_min_image", "u_block_max_image")),
    # storage blocks
    storage=("ObjCount", "BinTable", "BinStats", "Remap", "Ext", "Frames", "MeshVerts", "MeshFaces", "FaceNormals",
             "Labels", "CompCount", "SplitList", "SampleList", "TileList", "Resolved"),
    # samplers
    textures=("u_bins", "u_tri", "u_normal", "u_position", "u_colour_pack", "u_color", "u_material", "u_reflected",
              "u_pack", "u_block_min", "u_block_max", "u_obj", "u_prev",
              "u_mnormal"),
)
