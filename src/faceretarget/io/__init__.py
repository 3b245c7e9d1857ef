"""Readers and writers: OBJ meshes and rigs, Live Link Face CSV, glTF binary (morph and head animation), ``.npz``,
OBJ sequences, C3D markers, BVH head motion and WAV audio.

Every reader raises :class:`~faceretarget.errors.InputFileError` (or a more specific
:class:`~faceretarget.errors.FaceRetargetError`) whose message names the file and the line, row,
shape or key at fault; every writer produces its output whole or not at all
(:mod:`faceretarget.io._atomic`) and raises :class:`~faceretarget.errors.OutputError` naming the
path it could not write.
"""

from .audio import read_audio
from .bvh import Bvh, BvhJoint, bvh_chain, make_head_bvh, read_bvh, write_bvh
from .c3d import read_c3d, write_c3d
from .gltf import glb_vertex_order, read_glb_head, read_glb_rig, read_glb_weights, write_glb, write_glb_head
from .livelinkface import LiveLinkFaceInfo, read_livelinkface, write_livelinkface
from .npz import read_npz_performance, write_npz
from .obj import read_obj, read_obj_sequence, read_obj_vertices, write_obj, write_obj_sequence
from .performance_io import read_performance, write_animation
from .rigio import load_rig, load_rig_npz, save_rig_npz, save_rig_obj

__all__ = [
    "read_obj",
    "read_obj_vertices",
    "write_obj",
    "read_obj_sequence",
    "write_obj_sequence",
    "load_rig",
    "save_rig_obj",
    "save_rig_npz",
    "load_rig_npz",
    "read_livelinkface",
    "write_livelinkface",
    "LiveLinkFaceInfo",
    "write_glb",
    "read_glb_weights",
    "read_glb_rig",
    "glb_vertex_order",
    "write_npz",
    "read_npz_performance",
    "read_performance",
    "write_animation",
    "read_c3d",
    "write_c3d",
    "read_audio",
    "Bvh",
    "BvhJoint",
    "bvh_chain",
    "make_head_bvh",
    "read_bvh",
    "write_bvh",
    "write_glb_head",
    "read_glb_head",
]
