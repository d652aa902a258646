"""Neuroglancer precomputed segmentation layers with multi-resolution meshes.

A layer is a folder (Neuroglancer's "precomputed" format, served as static
files):

``info``
    The segmentation volume's metadata: ``type`` segmentation, the label
    ``data_type``, one scale with the volume's ``size``, its ``resolution`` in
    nanometres (the spacing and the volume's unit) and ``voxel_offset`` 0, and
    ``mesh``: the name of the mesh folder.
``mesh/info``
    ``@type`` ``neuroglancer_multilod_draco``, the ``vertex_quantization_bits``
    (10 or 16), the ``transform`` from the stored model space (here the volume's
    index space: sample (i, j, k) at (i, j, k)) to nanometres (the volume's
    index-to-world affine, origin and rotation included, times nanometres per
    unit), and ``lod_scale_multiplier`` 1.
``mesh/<id>.index``, ``mesh/<id>``
    Per object, the manifest (octree chunk shape, grid origin, the levels of
    detail with their scales, the fragments' positions and byte sizes) and the
    fragments: Draco meshes whose integer positions are the vertices quantized
    in their fragment's box.

Levels of detail: level 0 is the mesh as extracted; level k (k >= 1) is it
decimated, by the function the caller passes (the jobs pass isoconvert's bounded
collapse, :func:`isoconvert.post.decimate.collapse`), to within ``2**(k - 1)``
index units both ways. Each level is one fragment whose
octree node starts at the object's bounding box: its node at level k is ``2**k``
boxes wide, so the object lies in the node's first octant and no triangle
crosses the node's 2x2x2 partition, as the format asks. Quantizing in that box
moves a vertex by at most half a step: ``box * 2**k / (2**bits - 1) / 2``
per axis.

With ``chunk`` the octree's finest nodes are that many index units a side instead,
and each level is cut into the nodes it crosses (:mod:`.octree`): the planes lie
at ``phase`` of the voxel grid, through the samples for isosurfaces, whose triangles
then stay whole at level 0 (each lies in one cell between samples).

With ``sharded`` the manifests and fragments go into shard files
(:mod:`.shards`, the identity hash).

With ``legacy`` the meshes are in the legacy single-resolution format instead
(``neuroglancer_legacy_mesh``, for tools that read no other): per object a JSON
manifest ``<id>:0`` naming one fragment ``<id>:0:0``, which holds the vertex count,
the vertices as float32 nanometres and the triangles as uint32, one level, not
sharded (:mod:`.legacy`).

With ``volume`` the layer also holds the labels' voxels
(:mod:`.volume`). A precomputed volume has no origin
or direction: voxel (i, j, k) fills ``[i, i + 1) x resolution`` per axis. The
meshes then go to that same frame (index coordinates plus half a voxel, times the
resolution), so that each surface lies on its voxels in the viewer; the volume's
origin and direction are not stored (a note says so where they are not trivial).

Each object is encoded by :func:`.tasks.encode_object`, a function of arrays and scalars,
which the caller may run elsewhere (``map_objects``: the jobs send each object to a
Dask cluster's workers with ``--scheduler``, as :func:`.tasks.write_object`). There each
task writes its object's fragment data into the layer's part folder itself (the
folder is on a file system the workers share) and sends back only the manifest;
the client writes the manifests (or, sharded, the shards from the tasks' files)
and renames the folder into place. A worker that does not see the folder, or may
not write there, sends the data back instead.

An object given in parts (a label's, from the surface net) and cut into fragments
is encoded a few rows of level-0 nodes (along x) at a time instead
(:func:`.tasks.encode_rows`, one task each, :func:`.tasks.row_tasks`), never built whole;
when it is large (:data:`.tasks.LARGE_OBJECT`) its coarser levels are collapsed in slabs
here (:func:`.tasks._coarse_levels`).

The layer itself, its checks and files, is :mod:`.layer`'s
(:func:`write_precomputed`).
"""

from .layer import (
    LAYER_ONLY,
    QUANTIZATION_BITS,
    check_layer,
    data_type_for,
    layer_transform,
    not_a_file,
    write_precomputed,
)
from .shards import object_file
from .tasks import (
    Collapse,
    ObjectMap,
    Preceding,
    collapse_slab,
    encode_node,
    encode_object,
    encode_rows,
    write_object,
)

__all__ = [
    "LAYER_ONLY",
    "QUANTIZATION_BITS",
    "Collapse",
    "ObjectMap",
    "Preceding",
    "check_layer",
    "collapse_slab",
    "data_type_for",
    "encode_node",
    "encode_object",
    "encode_rows",
    "layer_transform",
    "not_a_file",
    "object_file",
    "write_object",
    "write_precomputed",
]
