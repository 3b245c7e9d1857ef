"""Every file format: rigs and meshes (OBJ, glTF), takes (Live Link Face CSV, C3D, ``.npz``, OBJ
sequences, glTF weight animation), head motion (BVH, SMPL-X, glTF head node, Live Link Face head
columns), audio (WAV), video (any container ffmpeg reads, through PyAV), keyshape folders; retargeting
targets that are not meshes: control tables, BVH / glTF skeleton poses, SVG drawings and 2-D point sets.

:func:`read_performance` and :func:`write_animation` choose the format from the path through one
extension registry; each format's module documents its layout.  :func:`read_character` reads a whole
character (glTF / VRM, FBX, Blender, USD, OBJ folder, ``.npz`` rig).
Every reader raises :class:`~faceretarget.errors.InputFileError` (or a more specific
:class:`~faceretarget.errors.FaceRetargetError`) whose message names the file and the line, row,
shape or key at fault; every writer produces its output whole or not at all
(:mod:`faceretarget.files`) and raises :class:`~faceretarget.errors.OutputError` naming the path
it could not write.

Format lists (tuples of extensions): ``READ_FORMATS`` / ``WRITE_FORMATS`` what :func:`read_performance`
/ :func:`write_animation` read and write (``"folder"`` for OBJ frames); ``HEAD_READ_FORMATS`` /
``HEAD_FORMATS`` what :func:`read_head_motion` / :func:`write_head_motion` read and write;
``CHARACTER_EXTENSIONS`` the character files :func:`read_character` reads (besides OBJ folders).

``__all__`` is the API: the readers and writers of each format, the data classes they return and the
format lists.  The helpers the rest of faceretarget and the Blender extension share (the extension
registry ``READERS`` / ``WRITERS`` / ``register_reader``, the Blender scene steps, the glTF document,
the per-route head readers, BVH and keyshape helpers, ``read_glb_rig`` (deprecated: call
:func:`read_character`) ...) are importable from here too, but are not part of it.
"""

# ``from ._mod import name as name``: a helper the rest of faceretarget (``from ..io import name``) or the
# Blender extension uses, importable from here but not part of the API (not in ``__all__``).
from ..files import atomic_dir as atomic_dir
from ..files import atomic_path as atomic_path
from ..files import check_output_path as check_output_path
from ..files import input_file as input_file
from ..files import load_npz_arrays as load_npz_arrays
from ..files import save_npz_arrays as save_npz_arrays
from ._audio import read_audio, write_audio
from ._blender import blender_timebase, import_bpy, write_blend, write_fbx
from ._blender_scene import HeadBone as HeadBone
from ._blender_scene import character_objects as character_objects
from ._blender_scene import head_bones as head_bones
from ._blender_scene import read_blender_scene_character as read_blender_scene_character
from ._blender_scene import run_steps as run_steps
from ._blender_scene import scene_action_steps as scene_action_steps
from ._blender_scene import scene_character_steps as scene_character_steps
from ._bvh import Bvh, read_bvh, write_bvh
from ._bvh import BvhJoint as BvhJoint
from ._bvh import bvh_chain as bvh_chain
from ._bvh import bvh_pose as bvh_pose
from ._bvh import bvh_with_pose as bvh_with_pose
from ._bvh import bvh_world_positions as bvh_world_positions
from ._bvh import make_head_bvh as make_head_bvh
from ._bvh import read_key_frames as read_key_frames
from ._c3d import read_c3d, write_c3d
from ._character import CHARACTER_EXTENSIONS, read_character
from ._character import character_format as character_format
from ._character import character_from_rig as character_from_rig
from ._character import check_character_route as check_character_route
from ._character import is_character_file as is_character_file
from ._character_write import WRITE_BACK as WRITE_BACK
from ._character_write import write_character_animation
from ._character_write import write_plain_glb as write_plain_glb
from ._character_write import write_vrma as write_vrma
from ._character_write import writes_back as writes_back
from ._controls import CONTROL_TABLE_FORMATS as CONTROL_TABLE_FORMATS
from ._controls import ControlTable, read_control_table, write_control_table
from ._controls import write_control_curves as write_control_curves
from ._controls import write_control_template as write_control_template
from ._gltf import glb_vertex_order as glb_vertex_order
from ._gltf import read_glb_head, read_glb_weights, write_glb, write_glb_head
from ._gltf import read_glb_rig as read_glb_rig
from ._gltf_scene import GltfDocument as GltfDocument
from ._gltf_scene import read_gltf_character as read_gltf_character
from ._gltf_skin import GlbSkeleton, read_glb_skeleton, write_glb_skeleton
from ._head import HEAD_READ_FORMATS, read_head_motion, read_head_take
from ._head import read_bvh_head as read_bvh_head
from ._head import read_glb_skin_head as read_glb_skin_head
from ._head import read_marker_head as read_marker_head
from ._head import read_smplx_head as read_smplx_head
from ._keyshapes import is_keyshape_folder as is_keyshape_folder
from ._keyshapes import keyshape_filename as keyshape_filename
from ._keyshapes import read_keys as read_keys
from ._keyshapes import read_keyshapes, write_keyshapes
from ._keyshapes import read_marker_labels as read_marker_labels
from ._livelinkface import LiveLinkFaceInfo, read_livelinkface, write_livelinkface
from ._livelinkstream import LLF_PACKET_VERSION as LLF_PACKET_VERSION
from ._livelinkstream import LLF_PORT as LLF_PORT
from ._livelinkstream import LiveLinkFacePacket, livelinkface_packet, read_livelinkface_packet
from ._livelinkstream import arkit_curve_map as arkit_curve_map
from ._npz import read_npz_performance, write_npz
from ._obj import read_obj, write_obj
from ._obj import read_obj_sequence as read_obj_sequence
from ._obj import read_obj_vertices as read_obj_vertices
from ._obj import write_obj_sequence as write_obj_sequence
from ._registry import (
    HEAD_FORMATS,
    READ_FORMATS,
    WRITE_FORMATS,
    read_performance,
    write_animation,
    write_head_motion,
)
from ._registry import MAX_TAKE_WEIGHT as MAX_TAKE_WEIGHT
from ._registry import READERS as READERS
from ._registry import WRITERS as WRITERS
from ._registry import Animation as Animation
from ._registry import holds_head as holds_head
from ._registry import register_reader as register_reader
from ._registry import register_writer as register_writer
from ._rig import read_rig, read_rig_npz, write_rig, write_rig_npz
from ._shapes_write import SHAPES_WRITE as SHAPES_WRITE
from ._shapes_write import write_character_shapes
from ._svg import DRAWING_FORMATS as DRAWING_FORMATS
from ._svg import POINT_SET_FORMATS as POINT_SET_FORMATS
from ._svg import Drawing, read_svg_animation, read_svg_drawing, write_svg_animation
from ._svg import read_point_set as read_point_set
from ._svg import render_drawing as render_drawing
from ._svg import write_drawing_preview as write_drawing_preview
from ._svg import write_svg_frames as write_svg_frames
from ._usd import USD_FORMATS as USD_FORMATS
from ._usd import usd_prim_names as usd_prim_names
from ._usd import write_usd
from ._video import VideoInfo, iter_frames, probe_video, write_video
from ._video import read_video_audio as read_video_audio

__all__ = [
    # characters as users bring them
    "read_character", "write_character_animation", "write_character_shapes", "CHARACTER_EXTENSIONS",
    # takes and animations by extension
    "read_performance", "write_animation", "READ_FORMATS", "WRITE_FORMATS",
    # head motion
    "read_head_motion", "read_head_take", "write_head_motion", "HEAD_READ_FORMATS", "HEAD_FORMATS",
    # rigs, meshes, keyshapes
    "read_rig", "write_rig", "read_rig_npz", "write_rig_npz", "read_obj", "write_obj",
    "read_keyshapes", "write_keyshapes",
    # Live Link Face: CSV takes and UDP packets
    "read_livelinkface", "write_livelinkface", "LiveLinkFaceInfo",
    "livelinkface_packet", "read_livelinkface_packet", "LiveLinkFacePacket",
    # glTF: weight animation, head node, skeleton poses
    "write_glb", "read_glb_weights", "write_glb_head", "read_glb_head",
    "read_glb_skeleton", "write_glb_skeleton", "GlbSkeleton",
    # USD, Blender, .npz, C3D, BVH
    "write_usd", "write_blend", "write_fbx", "blender_timebase", "import_bpy",
    "read_npz_performance", "write_npz", "read_c3d", "write_c3d", "read_bvh", "write_bvh", "Bvh",
    # audio and video
    "read_audio", "write_audio", "probe_video", "VideoInfo", "iter_frames", "write_video",
    # control tables and drawings (targets that are not meshes)
    "read_control_table", "write_control_table", "ControlTable",
    "read_svg_drawing", "read_svg_animation", "write_svg_animation", "Drawing",
]
