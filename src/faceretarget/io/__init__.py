"""Every file format: rigs and meshes (OBJ, glTF), takes (Live Link Face CSV, C3D, ``.npz``, OBJ
sequences, glTF weight animation), head motion (BVH, SMPL-X, glTF head node, Live Link Face head
columns), audio (WAV), video (any container ffmpeg reads, through PyAV), keyshape folders; retargeting
targets that are not meshes: control tables, BVH / glTF skeleton poses, SVG drawings and 2-D point sets.

:func:`read_performance` and :func:`write_animation` choose the format from the path through one
extension registry (:data:`READERS`, :data:`WRITERS`); each format's module documents its layout.
Every reader raises :class:`~faceretarget.errors.InputFileError` (or a more specific
:class:`~faceretarget.errors.FaceRetargetError`) whose message names the file and the line, row,
shape or key at fault; every writer produces its output whole or not at all
(:mod:`faceretarget.files`) and raises :class:`~faceretarget.errors.OutputError` naming the path
it could not write.
"""

from ..files import atomic_dir, atomic_path, check_output_path, input_file, load_npz_arrays, save_npz_arrays
from ._audio import read_audio, write_audio
from ._blender import blender_timebase, import_bpy, write_blend, write_fbx
from ._blender_scene import (
    HeadBone,
    character_objects,
    head_bones,
    read_blender_scene_character,
    run_steps,
    scene_action_steps,
    scene_character_steps,
)
from ._bvh import (
    Bvh,
    BvhJoint,
    bvh_chain,
    bvh_pose,
    bvh_with_pose,
    bvh_world_positions,
    make_head_bvh,
    read_bvh,
    read_key_frames,
    write_bvh,
)
from ._c3d import read_c3d, write_c3d
from ._character import (
    CHARACTER_EXTENSIONS,
    character_format,
    character_from_rig,
    check_character_route,
    is_character_file,
    read_character,
)
from ._character_write import WRITE_BACK, write_character_animation, write_plain_glb, write_vrma, writes_back
from ._controls import (
    CONTROL_TABLE_FORMATS,
    ControlTable,
    read_control_table,
    write_control_curves,
    write_control_table,
    write_control_template,
)
from ._gltf import glb_vertex_order, read_glb_head, read_glb_rig, read_glb_weights, write_glb, write_glb_head
from ._gltf_scene import GltfDocument, read_gltf_character
from ._gltf_skin import GlbSkeleton, read_glb_skeleton, write_glb_skeleton
from ._head import (
    HEAD_READ_FORMATS,
    read_bvh_head,
    read_glb_skin_head,
    read_head_motion,
    read_head_take,
    read_marker_head,
    read_smplx_head,
)
from ._keyshapes import (
    is_keyshape_folder,
    keyshape_filename,
    read_keys,
    read_keyshapes,
    read_marker_labels,
    write_keyshapes,
)
from ._livelinkface import LiveLinkFaceInfo, read_livelinkface, write_livelinkface
from ._livelinkstream import (
    LLF_PACKET_VERSION,
    LLF_PORT,
    LiveLinkFacePacket,
    arkit_curve_map,
    livelinkface_packet,
    read_livelinkface_packet,
)
from ._npz import read_npz_performance, write_npz
from ._obj import read_obj, read_obj_sequence, read_obj_vertices, write_obj, write_obj_sequence
from ._registry import (
    HEAD_FORMATS,
    MAX_TAKE_WEIGHT,
    READ_FORMATS,
    READERS,
    WRITE_FORMATS,
    WRITERS,
    Animation,
    holds_head,
    read_performance,
    register_reader,
    register_writer,
    write_animation,
    write_head_motion,
)
from ._rig import read_rig, read_rig_npz, write_rig, write_rig_npz
from ._shapes_write import SHAPES_WRITE, write_character_shapes
from ._svg import (
    DRAWING_FORMATS,
    POINT_SET_FORMATS,
    Drawing,
    read_point_set,
    read_svg_animation,
    read_svg_drawing,
    render_drawing,
    write_drawing_preview,
    write_svg_animation,
    write_svg_frames,
)
from ._usd import USD_FORMATS, usd_prim_names, write_usd
from ._video import VideoInfo, iter_frames, probe_video, read_video_audio, write_video

__all__ = [
    "read_character", "character_from_rig", "is_character_file", "CHARACTER_EXTENSIONS", "read_gltf_character",
    "character_format", "check_character_route",
    "read_blender_scene_character", "scene_character_steps", "scene_action_steps", "character_objects", "run_steps",
    "head_bones", "HeadBone",
    "GltfDocument", "write_character_shapes", "SHAPES_WRITE",
    "write_character_animation", "writes_back", "WRITE_BACK", "write_plain_glb", "write_vrma",
    "read_obj", "read_obj_vertices", "write_obj", "read_obj_sequence", "write_obj_sequence",
    "read_rig", "write_rig", "write_rig_npz", "read_rig_npz",
    "read_livelinkface", "write_livelinkface", "LiveLinkFaceInfo",
    "livelinkface_packet", "read_livelinkface_packet", "LiveLinkFacePacket", "arkit_curve_map", "LLF_PORT",
    "LLF_PACKET_VERSION",
    "write_glb", "read_glb_weights", "read_glb_rig", "glb_vertex_order", "write_glb_head", "read_glb_head",
    "write_usd", "usd_prim_names", "USD_FORMATS",
    "write_blend", "write_fbx", "blender_timebase", "import_bpy",
    "write_npz", "read_npz_performance",
    "read_performance", "MAX_TAKE_WEIGHT", "write_animation", "READ_FORMATS", "WRITE_FORMATS", "READERS", "WRITERS",
    "register_reader", "register_writer", "Animation", "holds_head",
    "read_c3d", "write_c3d",
    "read_audio", "write_audio",
    "Bvh", "BvhJoint", "bvh_chain", "make_head_bvh", "read_bvh", "write_bvh", "bvh_pose", "bvh_world_positions",
    "bvh_with_pose", "read_key_frames", "GlbSkeleton", "write_glb_skeleton", "read_glb_skeleton",
    "ControlTable", "read_control_table", "write_control_template", "write_control_table",
    "write_control_curves", "CONTROL_TABLE_FORMATS",
    "Drawing", "read_svg_drawing", "read_point_set", "write_svg_animation", "write_svg_frames", "read_svg_animation",
    "render_drawing", "write_drawing_preview", "DRAWING_FORMATS", "POINT_SET_FORMATS",
    "write_head_motion", "HEAD_FORMATS", "HEAD_READ_FORMATS", "read_head_motion", "read_head_take",
    "read_bvh_head", "read_glb_skin_head", "read_smplx_head", "read_marker_head",
    "write_keyshapes", "read_keyshapes", "read_marker_labels", "is_keyshape_folder", "keyshape_filename", "read_keys",
    "VideoInfo", "probe_video", "iter_frames", "read_video_audio", "write_video",
    "atomic_path", "atomic_dir", "check_output_path", "input_file", "load_npz_arrays", "save_npz_arrays",
]
