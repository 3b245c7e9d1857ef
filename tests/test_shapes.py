"""Expression shapes generated for a character with only a neutral face (issue 25): the packaged template,
the neutral character's head and landmarks, the lids and lips of the generated shapes against their
targets, their landmark motion against the artist's, the main job driving them, the command and its
OBJ folder."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from faceretarget.characters import (
    apply_landmark_record,
    generate_shapes,
    landmark_record,
    load_character,
    load_template,
)
from faceretarget.cli import main
from faceretarget.io import read_character, read_rig
from faceretarget.names import normalize_name
from faceretarget.pipelines import animate, capture_take
from faceretarget.transfer import packaged_template_path, shape_delta, shape_metrics, teeth_showing_px

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
from _character_checks import hide_shapes  # noqa: E402


@pytest.fixture(scope="module")
def arkit_generated(data_dir):
    """arkit-face with its shapes hidden, generated from the packaged ICT-FaceKit template."""
    ref = load_character(data_dir / "arkit-face")
    hidden = hide_shapes(read_character(data_dir / "arkit-face"))
    hidden.landmarks = ref.landmarks
    lines = []
    gen = generate_shapes(hidden, progress=lines.append)
    return ref, gen, gen.apply(), lines


def test_packaged_template_matches_ict(data_dir):
    """The wheel's template is ICT-FaceKit in metres, float16 deltas within 20 micrometres, under ARKit names
    (browInnerUp the sum of its halves; no tongueOut)."""
    assert packaged_template_path().is_file()
    t = load_template("ict-face")
    ict = read_rig(data_dir / "ict-face")
    k = ict.mm_per_unit / 1000.0
    assert np.allclose(t.vertices, ict.neutral.vertices * k, atol=1e-6)
    names = list(ict.source_names or ict.names)
    full = ict.deltas[names.index("browInnerUp_L")] + ict.deltas[names.index("browInnerUp_R")]
    assert np.abs(t.shapes["browInnerUp"] - full * k).max() < 2e-5
    assert np.abs(t.shapes["eyeBlinkLeft"] - ict.deltas[names.index("eyeBlink_L")] * k).max() < 2e-5
    assert len(t.shapes) == 51 and "tongueOut" not in t.shapes
    assert any("tongueOut" in n for n in t.notes)


@pytest.mark.parametrize("rel", ["characters/valid/AIAN_F_1_Busi.glb", "characters/rocketbox/Female_Adult_01_facial.fbx"])
def test_neutral_character_head_and_landmarks(data_dir, rel):
    """Shapes hidden: the head mesh is chosen and the 68 landmarks are found on it, around the face: the
    eyes above the mouth, the outer eye corners 8-11 cm apart, every point within the head."""
    pytest.importorskip("mediapipe")
    full = read_character(data_dir / rel)
    with pytest.raises(Exception, match="no face shapes"):
        load_character(hide_shapes(read_character(data_dir / rel)))
    hidden = hide_shapes(read_character(data_dir / rel))
    hidden.path = None
    ch = load_character(hidden, need_shapes=False)
    assert ch.landmarks is not None and ch.landmarks.mesh == full.face_meshes()[0]
    P = ch.landmark_positions()
    eye = float(np.linalg.norm(P[36] - P[45]))
    assert 0.08 < eye < 0.11
    assert P[36:48, 1].mean() - P[48:68, 1].mean() > 0.03                  # +Y up in both files
    d = np.linalg.norm(P - P[17:68].mean(axis=0), axis=1)
    assert d[17:].max() < 1.0 * eye and d[:17].max() < 1.6 * eye          # none through a hole to the back



def _bangs(ch, lm, size):
    """A dense opaque hair sheet a little in front of the face from above its head to just under the brows (a
    VRoid avatar's bangs): 8,100 vertices, more in the head than the face mesh has."""
    from scipy.spatial import cKDTree

    from faceretarget.character import Material, SceneMesh
    from faceretarget.mesh import Mesh

    V = ch.meshes[0].mesh.vertices
    xs = np.linspace(lm[:, 0].min() - 0.4 * size, lm[:, 0].max() + 0.4 * size, 90)
    ys = np.linspace(lm[17:27, 1].min() - 0.15 * size, V[:, 1].max() + 0.05 * size, 90)
    tree = cKDTree(V[:, :2])
    G = []
    for y in ys:
        for x in xs:
            near = tree.query_ball_point([x, y], 0.12 * size)
            G.append([x, y, (V[near, 2].max() if near else V[:, 2].min()) + 0.06 * size])
    n = len(xs)
    quads = [[r * n + c, r * n + c + 1, (r + 1) * n + c + 1, (r + 1) * n + c]
             for r in range(len(ys) - 1) for c in range(n - 1)]
    return SceneMesh(name="Hair", ref="node:hair", mesh=Mesh(np.array(G), np.full(len(quads), 4), np.ravel(quads)),
                     materials=[Material(name="hair", color=np.array([0.09, 0.05, 0.03, 1.0]))])


def test_bangs_over_the_brows_do_not_take_the_face(data_dir):
    """Issue 34: a character without face shapes whose hair mesh outnumbers its face in the head (VRoid bangs
    over the forehead): the head mesh guessed is the hair, but the face is the mesh the tracker found it on;
    'character shapes' refused such an avatar ("43 of the 68 landmarks ... are not over the face mesh
    'Hair'"). Found through the bangs: nose, eyes and mouth within 5 % of the eye-corner distance of the
    hand-made points (3.5 / 4.5 / 3.2 % measured), the hidden brows and the jaw line within 15 % (10.7, 10.4;
    6.5 and 5.2 without the hair)."""
    pytest.importorskip("mediapipe")
    ref = load_character(data_dir / "arkit-face")
    lm = ref.landmark_positions()
    size = float(np.linalg.norm(lm[36] - lm[45]))
    ch = hide_shapes(read_character(data_dir / "arkit-face"))
    ch.path, ch.landmarks = None, None
    ch.meshes.append(_bangs(ch, lm, size))
    assert ch.head_mesh() == 1                                             # the guess: the hair
    lines = []
    got = load_character(ch, need_shapes=False, log=lines.append)
    assert got.landmarks.mesh == 0 and got.neutral_head == 0 and got.primary == 0
    assert any("the face is on 'arkit-face'" in ln and "not on 'Hair'" in ln for ln in lines), lines
    e = np.linalg.norm(got.landmark_positions() - lm, axis=1) / size
    print(f"through bangs: jaw {e[:17].mean():.3f}, brows {e[17:27].mean():.3f}, rest {e[27:].mean():.3f}")
    assert e[27:].mean() <= 0.05 and e[17:27].mean() <= 0.15 and e[:17].mean() <= 0.15
    # read back (the landmark cache's record): the head mesh follows the landmarks, not the guess
    again = hide_shapes(read_character(data_dir / "arkit-face"))
    again.path, again.landmarks = None, None
    again.meshes.append(_bangs(again, lm, size))
    again.neutral_head = again.head_mesh()
    assert again.neutral_head == 1 and apply_landmark_record(again, landmark_record(got))
    assert again.neutral_head == 0 and again.primary == 0


# slow: its fixture generates the ARKit set on three characters once for the module (~10 s)
def test_generated_lids_lips_surface_mirror(arkit_generated):
    ref, gen, ch, lines = arkit_generated
    assert len(gen.shape_names) == 51
    assert any(ln.startswith("shape 51/51") for ln in lines)               # progress, one line per shape
    m = shape_metrics(ch)
    art = shape_metrics(ref)
    assert m["blink_gap_pct"] <= 10.0                                     # the lids close
    assert m["lip_gap_pct"] <= 10.0                                       # the lips meet on the open jaw
    # the artist's own sculpts fold 168 triangles inside the lips at weight 1; the generated ones none (94
    # before the untangling kept every triangle facing its way, alone and on the open jaw)
    assert art["inverted_triangles"] > 0 and m["inverted_triangles"] == 0
    assert m["mirror_err_pct"] <= 5.0
    # every deltas array world-space metres, finite, and on the face only
    d = gen.added["arkit-face"]["jawOpen"]
    assert d.dtype == np.float32 and np.isfinite(d).all() and 0.005 < np.abs(d).max() < 0.05


def test_landmark_motion_points_the_artists_way(arkit_generated):
    """On the large shapes, the generated landmark motion points the way of the artist's (measured median
    0.91; the two artists' own shapes agree to about 0.97 after transfer, issue 25)."""
    ref, gen, ch, _ = arkit_generated
    cos, size = [], []
    for n in gen.shape_names:
        a, b = shape_delta(ref, n), shape_delta(ch, n)
        la, lb = ref.landmarks.positions(a), ch.landmarks.positions(b)
        cos.append(float((la * lb).sum() / np.linalg.norm(la) / np.linalg.norm(lb)))
        size.append(np.linalg.norm(la))
    big = np.asarray(size) >= np.median(size)
    assert np.median(np.asarray(cos)[big]) >= 0.85
    jaw = gen.shape_names.index("jawOpen")
    assert cos[jaw] >= 0.9


# slow: two full shape generations on a real avatar (keep, then replace) (~13 s)
def test_kept_shapes_and_replace(data_dir):
    """Shapes the character has are kept (and said) unless replace."""
    ch = load_character(data_dir / "arkit-face")
    gen = generate_shapes(ch, shapes="eyeBlinkLeft,jawOpen")
    assert gen.added == {} and gen.skipped == ["eyeBlinkLeft", "jawOpen"]
    gen = generate_shapes(ch, shapes="jawOpen", replace=True)
    new = gen.apply()
    assert new.meshes[0].n_shapes == ch.meshes[0].n_shapes                 # replaced, not appended
    k = [normalize_name(n) for n in new.meshes[0].shape_names].index("jawOpen")
    assert np.allclose(new.meshes[0].deltas[k], gen.added["arkit-face"]["jawOpen"])
    assert ch.meshes[0].deltas is not new.meshes[0].deltas                 # the input is unchanged


@pytest.fixture(scope="module")
def valid_generated(data_dir):
    """Black_M_2_Busi with its shapes hidden, its landmarks found on the neutral, the ARKit set generated."""
    pytest.importorskip("mediapipe")
    path = data_dir / "characters" / "valid" / "Black_M_2_Busi.glb"
    hidden = hide_shapes(read_character(path))
    hidden.path = None
    ch = load_character(hidden, need_shapes=False)
    gen = generate_shapes(ch)
    drive = gen.apply()
    return ch, gen, drive, shape_metrics(drive)


# slow: deformation transfer of 51 shapes onto a 22k-vertex VALID avatar, then the main job on a video (~18 s)
def test_neutral_avatar_gets_driven(data_dir, valid_generated):
    """A VALID avatar with its shapes hidden: head mesh and landmarks found on the neutral, 51 shapes on the
    head, teeth and eyes; blinks close over its own eyeballs; the main job drives the shapes."""
    ch, gen, drive, m = valid_generated
    assert ch.meshes[ch.landmarks.mesh].name == "H_DDS_HighRes" and ch.neutral_head == ch.landmarks.mesh
    assert gen.timings["total"] < 60
    assert {"H_DDS_HighRes", "h_TeethDown", "h_L_eye", "h_R_eye"} <= set(gen.added)
    assert "jawOpen" in gen.added["h_TeethDown"] and "h_TeethUp" not in gen.added       # lower teeth ride the jaw
    assert set(gen.added["h_L_eye"]) == {"eyeLookDownLeft", "eyeLookInLeft", "eyeLookOutLeft", "eyeLookUpLeft"}
    assert m["blink_gap_pct"] <= 10.0 and m["lid_inside_eye"] == 0 and m["lip_gap_pct"] <= 10.0
    take = capture_take(data_dir / "video" / "WDA_KatieHill_000.mp4", neutral_percentile=5.0, max_frames=150)
    r = animate(take, drive, shapes="arkit")
    assert r.mouth_corr >= 0.9
    assert "jawOpen" in r.names


def test_avatar_shapes_fold_nothing_and_keep_the_lips_out_of_the_teeth(valid_generated):
    """On the VALID avatar no generated shape (nor jawOpen plus a mouth shape) turns a triangle over (405
    did), and jawOpen + mouthClose puts no lip vertex inside the teeth (4 did).  The inside of its mouth,
    a piece of the head mesh sewn to the inner lips along a seam, continues the skin's motion: taken for teeth
    and split at the lips' line it tore, and its convex hull held the lips."""
    ch, gen, drive, m = valid_generated
    assert m["inverted_triangles"] == 0
    assert m["lips_in_teeth"] == 0
    head = [(role, n) for name, role, _, n in gen.info["parts"] if name == "H_DDS_HighRes"]
    assert head and all(role == "sewn" for role, _ in head)                # the inside of the mouth, the ears
    assert m["lip_gap_pct"] <= 1.0                                         # 1.35 % when lips were told by height


def test_avatar_left_right_shapes_mirror(valid_generated):
    """Left/right pairs mirror each other within 5 % but the blinks: this avatar's two eye openings are not
    mirror images (one 17 % taller than the other), each blink closes its own, and the two differ by less than
    the openings do (12.5 %; made mirror images, the lids stayed 21-42 % open at the worst rim point)."""
    import copy
    import dataclasses

    from faceretarget.character import character_frame
    from faceretarget.transfer import components, lid_margins, mirror_err_pct

    ch, gen, drive, m = valid_generated
    no_blinks = copy.copy(drive)
    no_blinks.meshes = []
    for mesh in drive.meshes:
        k = [i for i, n in enumerate(mesh.shape_names) if not n.startswith("eyeBlink")]
        no_blinks.meshes.append(dataclasses.replace(mesh, shape_names=[mesh.shape_names[i] for i in k],
                                                    deltas=mesh.deltas[k], shape_refs=[mesh.shape_refs[i] for i in k]))
    assert mirror_err_pct(no_blinks) <= 5.0
    head = drive.meshes[drive.landmarks.mesh]
    V, T = head.mesh.vertices.astype(float), head.mesh.triangles()
    lab = components(len(V), T)
    skin = lab == np.bincount(lab[drive.landmarks.triangles.ravel()]).argmax()
    gaps = []
    for rim in lid_margins(V, T[skin[T].all(axis=1)], drive.landmark_positions(), character_frame(drive)):
        g = np.linalg.norm(V[rim.vertices] - np.einsum("nk,nkd->nd", rim.weight, V[rim.partner]), axis=1)
        gaps.append(float(np.median(g[g >= g.max() / 3])))
    openings_differ = 100.0 * abs(gaps[0] - gaps[1]) / np.mean(gaps)
    assert len(gaps) == 2 and openings_differ > 10.0
    assert m["mirror_err_pct"] <= openings_differ and m["blink_gap_pct"] <= 10.0


# slow: generates shapes on a VALID avatar and renders its mouth (~9 s)
def test_lower_teeth_stay_behind_the_lower_lip(data_dir):
    """jawOpen on a VALID avatar: the lower teeth and tongue ride the jaw behind the lip.  Fitted to the chin's
    skin alone they came out through the lower lip and chin: 1,829 pixels of a 400-pixel view of the mouth."""
    path = data_dir / "characters" / "valid" / "AIAN_F_1_Busi.glb"
    gen = generate_shapes(path, shapes="jawOpen")
    assert "jawOpen" in gen.added["h_TeethDown"]
    px = teeth_showing_px(gen.apply(), names=("jawOpen",))
    assert px is not None and px <= 40, px


def test_symmetric_head_blinks_are_mirror_images(data_dir):
    """Rocketbox's head is symmetric (0.3 % of the eye-corner distance): closed one side at a time, each on
    its own triangulation, its blinks were 6.7 % from mirror images; made mirror images again with both lids
    still closed (<= 10 % of the open gap) and no more triangles turned over, they are within 0.3 %."""
    from faceretarget.transfer import inverted_triangles, mirror_err_pct

    src = data_dir / "characters" / "rocketbox" / "Female_Adult_01_facial.fbx"
    hidden = hide_shapes(read_character(src))
    hidden.path = None                                        # its landmarks found again, on the neutral
    gen = generate_shapes(hidden, shapes=["eyeBlinkLeft", "eyeBlinkRight"])
    drive = gen.apply()
    assert any(n.startswith("the blinks made mirror images") for n in gen.notes), gen.notes
    assert mirror_err_pct(drive) <= 1.0
    m = shape_metrics(drive)
    assert m["blink_gap_pct"] <= 10.0 and m["lid_inside_eye"] == 0
    assert inverted_triangles(drive) <= 4           # the underside of its upper lids, as before (issue 34)


def _rotated(ch, R: np.ndarray, *, frame: bool = True):
    """A copy of the character turned by the rotation ``R`` (3, 3): its meshes, shapes and joints; with
    ``frame`` its up and front too (a file that holds it that way up), else they stay (a head the file holds
    turned)."""
    import copy

    out = copy.deepcopy(ch)
    for m in out.meshes:
        m.mesh.vertices = m.mesh.vertices @ R.T
        if m.deltas is not None and len(m.deltas):
            m.deltas = (m.deltas @ R.T).astype(m.deltas.dtype)
    R4 = np.eye(4)
    R4[:3, :3] = R
    for j in out.joints:
        j.world = R4 @ j.world
    if frame:
        out.up = None if ch.up is None else R @ ch.up
        out.front = None if ch.front is None else R @ ch.front
    return out


def _turned_z_up(ch):
    """A copy of the character turned as a Z-up file holds it (Blender, a Z-up USD or FBX): y -> z, z -> -y."""
    R = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    return _rotated(ch, R), R


def test_blinks_close_on_a_z_up_character_as_on_a_y_up_one(data_dir):
    """Generation is the same whichever way up the file holds the face.  The blink's pins compared the
    template's lid gap in its own (Y-up) frame with its motion in the character's: on a Z-up character
    (Rocketbox saved as .blend) no lid pair counted as closing and the lids stayed 39.6 % open.  arkit-face
    turned Z-up, its landmarks given: its blinks are the Y-up ones turned, and closed."""
    ref = load_character(data_dir / "arkit-face")
    hidden = hide_shapes(read_character(data_dir / "arkit-face"))
    hidden.landmarks = ref.landmarks
    turned, R = _turned_z_up(hidden)
    names = ["eyeBlinkLeft", "eyeBlinkRight"]
    a = generate_shapes(hidden, shapes=names).apply()
    b = generate_shapes(turned, shapes=names).apply()
    lm = a.landmark_positions()
    eoc = float(np.linalg.norm(lm[36] - lm[45]))
    for n in names:
        da, db = shape_delta(a, n).astype(float), shape_delta(b, n).astype(float)
        assert np.abs(da).max() > 0.05 * eoc                              # the lid moves
        assert np.linalg.norm(db - da @ R.T, axis=1).max() < 0.005 * eoc, n  # the same motion, turned
    ma, mb = shape_metrics(a), shape_metrics(b)
    assert mb["blink_gap_pct"] <= 10.0 and abs(mb["blink_gap_pct"] - ma["blink_gap_pct"]) < 0.5, (ma, mb)


def test_rocketbox_blinks_turn_no_triangle_over(chars):
    """Rocketbox's generated blinks folded the strip under each upper lid's edge back under the lid's front
    skin (4 triangles turned over, 175 degrees between the strip's normals and its neighbours', from 81): the
    eyeball push turned over again what the untangling had unfolded.  Now none, and the lids still close."""
    from faceretarget.transfer import inverted_triangles

    names = ["eyeBlinkLeft", "eyeBlinkRight"]
    gen = generate_shapes(chars / "rocketbox" / "Female_Adult_01_facial.fbx", shapes=names, replace=True)
    ch = gen.apply()
    assert inverted_triangles(ch, names) == 0
    m = shape_metrics(ch)
    assert m["blink_gap_pct"] <= 10.0 and m["lid_inside_eye"] == 0, m
    lm = ch.landmark_positions()
    eoc = float(np.linalg.norm(lm[36] - lm[45]))
    for n in names:
        assert np.abs(shape_delta(ch, n)).max() > 0.05 * eoc        # the lid moves


def test_a_side_shape_asked_alone_stays_on_its_side(data_dir, arkit_generated):
    """``--shapes mouthSmileLeft`` without its right mate was made symmetric on a symmetric face (averaged with
    its own mirror image: both corners half up, 49 % off the one generated with the whole set); it is the same
    one-sided smile now."""
    ref, _, whole, _ = arkit_generated
    hidden = hide_shapes(read_character(data_dir / "arkit-face"))
    hidden.landmarks = ref.landmarks
    one = generate_shapes(hidden, shapes=["mouthSmileLeft"]).apply()
    d, d0 = shape_delta(one, "mouthSmileLeft").astype(float), shape_delta(whole, "mouthSmileLeft").astype(float)
    moving = np.linalg.norm(d0, axis=1) > 0.1 * np.linalg.norm(d0, axis=1).max()
    assert np.sqrt(((d - d0)[moving] ** 2).sum(1).mean() / (d0[moving] ** 2).sum(1).mean()) < 0.05


def _cut_out(ch, faces: np.ndarray):
    """A copy of the character with the polygon ``faces`` (bool) of its landmark mesh cut off along a seam (as
    UV or material seams split a mesh): their border vertices doubled, the copies on the cut-out piece; and
    the (old, new) vertex pairs along the seam."""
    import copy

    from faceretarget.character import SurfacePoints
    from faceretarget.mesh import Mesh

    out = copy.deepcopy(ch)
    m = out.meshes[out.landmarks.mesh]
    M = m.mesh
    on = faces[np.repeat(np.arange(len(M.face_counts)), M.face_counts)]
    inside, outside = np.zeros(M.n_vertices, bool), np.zeros(M.n_vertices, bool)
    inside[M.face_indices[on]] = True
    outside[M.face_indices[~on]] = True
    seam = np.flatnonzero(inside & outside)
    new = np.full(M.n_vertices, -1)
    new[seam] = M.n_vertices + np.arange(len(seam))
    idx = M.face_indices.copy()
    moved = on & (new[idx] >= 0)
    idx[moved] = new[idx[moved]]
    T0 = M.triangles()
    m.mesh = Mesh(np.r_[M.vertices, M.vertices[seam]], M.face_counts.copy(), idx, name=M.name)
    m.deltas = np.concatenate([m.deltas, m.deltas[:, seam]], axis=1)
    T1, lm = m.mesh.triangles(), out.landmarks
    tri, S0 = lm.triangles.copy(), np.sort(T0, axis=1)
    for k in range(len(tri)):                           # the same triangle, on the piece where it now is
        hit = np.flatnonzero((S0 == np.sort(tri[k])).all(axis=1))
        if len(hit):
            tri[k] = [T1[hit[0]][list(T0[hit[0]]).index(v)] for v in tri[k]]
    out.landmarks = SurfacePoints(lm.mesh, tri, lm.bary.copy(), lm.source)
    return out, np.c_[seam, new[seam]]


def test_lips_or_a_lid_cut_out_by_a_seam_move_as_on_the_whole_mesh(data_dir, arkit_generated):
    """A face whose lips or lid a UV or material seam cuts out as their own piece: generation took the piece
    for another part (an eyeball, teeth), moved its landmarks onto the skin beside it and dragged the piece
    along (arkit-face's right lid cut out: the blink 18.8 % open, 2 triangles turned over; its lips: the mouth
    shapes 16-26 % off the whole mesh's).  A piece sewn on that carries the skin's surface on and holds
    landmarks is skin now, its seam held shut: each shape within 6 % of the whole mesh's, the seam closed to
    0.2 % of the eye-corner distance.  Rocketbox's pieces holding lid landmarks, the linings inside its lids
    (flaps on edges its skin is closed across), stay apart."""
    from matplotlib.path import Path as Polygon

    from faceretarget.transfer import landmark_skin

    ref, _, whole, _ = arkit_generated
    hidden = hide_shapes(read_character(data_dir / "arkit-face"))
    hidden.landmarks = ref.landmarks
    M = hidden.meshes[hidden.landmarks.mesh].mesh
    P = hidden.landmark_positions()
    eoc = float(np.linalg.norm(P[36] - P[45]))
    centres = np.add.reduceat(M.vertices[M.face_indices], np.r_[0, np.cumsum(M.face_counts)[:-1]]) / \
        M.face_counts[:, None]
    eye = P[36:42].mean(axis=0)
    a = np.linspace(0.0, 2 * np.pi, 40)
    cuts = {"lips": (Polygon(P[48:60, :2]), P[48:68, 2].mean()),
            "right lid": (Polygon(np.c_[eye[0] + 0.22 * eoc * np.cos(a), eye[1] + 0.12 * eoc * np.sin(a)]), eye[2])}
    names = ["jawOpen", "mouthSmileLeft", "mouthPucker", "eyeBlinkLeft", "eyeBlinkRight"]
    for what, (poly, z) in cuts.items():
        faces = poly.contains_points(centres[:, :2]) & (np.abs(centres[:, 2] - z) < 0.25 * eoc)
        cut, seam = _cut_out(hidden, faces)
        assert landmark_skin(cut).all(), what                          # the piece is skin
        gen = generate_shapes(cut, shapes=names)
        assert not any("another piece" in n for n in gen.notes), gen.notes
        out = gen.apply()
        for n in names:
            d, d0 = shape_delta(out, n).astype(float), shape_delta(whole, n).astype(float)
            moving = np.linalg.norm(d0, axis=1) > 0.1 * np.linalg.norm(d0, axis=1).max()
            off = np.sqrt(((d[:M.n_vertices] - d0)[moving] ** 2).sum(1).mean() / (d0[moving] ** 2).sum(1).mean())
            assert off < 0.06, (what, n, off)
            assert np.linalg.norm(d[seam[:, 0]] - d[seam[:, 1]], axis=1).max() < 0.002 * eoc, (what, n)
        assert shape_metrics(out)["blink_gap_pct"] < 3.0
    rb = load_character(data_dir / "characters" / "rocketbox" / "Female_Adult_01_facial.fbx")
    m = rb.meshes[rb.landmarks.mesh].mesh
    from faceretarget.transfer import components

    lab = components(m.n_vertices, m.triangles())
    assert len(np.unique(lab[rb.landmarks.triangles.ravel()])) > 1          # some lid points on the linings
    assert (landmark_skin(rb) == (lab == np.bincount(lab[rb.landmarks.triangles.ravel()]).argmax())).all()


def _yawed(ch, deg: float):
    """A copy of the character with its head turned ``deg`` about the up axis in the file (a head scanned or
    modelled turned); its file axes kept."""
    a = np.radians(deg)
    R = np.array([[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]])
    return _rotated(ch, R, frame=False), R


def test_face_frame_of_a_head_held_turned(data_dir):
    """A head the file holds turned gets the face's own frame from its symmetry plane (the file's axes and
    the landmark search's axis-aligned views gave the old frame): arkit-face turned 25 degrees and rolled 15
    is found turned by 25.0 / 15.0 degrees, facing where it faces; upright it keeps the file's axes."""
    from faceretarget.character import character_frame
    from faceretarget.characters import face_turn

    ref = load_character(data_dir / "arkit-face")
    assert face_turn(ref) is None and np.allclose(character_frame(ref), np.eye(3))
    turned, R = _yawed(ref, 25.0)
    turned.up, turned.front = np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0])   # as a search would leave it
    lines: list[str] = []
    assert face_turn(turned, lines.append) == pytest.approx(25.0, abs=0.1)
    assert np.degrees(np.arccos(turned.front @ (R @ [0.0, 0.0, 1.0]))) < 0.1
    assert "turned 25.0 degrees" in lines[0]
    c, s_ = np.cos(np.radians(15)), np.sin(np.radians(15))
    Rz = np.array([[c, -s_, 0.0], [s_, c, 0.0], [0.0, 0.0, 1.0]])
    rolled = _rotated(ref, Rz, frame=False)
    rolled.up, rolled.front = np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0])
    assert face_turn(rolled) == pytest.approx(15.0, abs=0.1)
    assert np.degrees(np.arccos(rolled.up @ (Rz @ [0.0, 1.0, 0.0]))) < 0.1


def test_a_head_nodding_in_its_file_is_looked_at_square(data_dir, tmp_path, monkeypatch):
    """A pitch leaves no trace in the symmetry plane; the landmarker's own pose on the render does (a 17-degree
    nod reads 16.3, upright faces 1.1-5.6): arkit-face written nodding 17 degrees is tipped back by more than 8,
    and its landmarks, found square to it, lie where the upright copy's do (the jaw line was 22 % of the
    eye-corner distance off, picked from above)."""
    pytest.importorskip("mediapipe")
    from faceretarget.characters import PITCH_BIAS_DEG, PITCH_TOLERANCE_DEG, face_pitch_turn
    from faceretarget.io import write_glb
    from faceretarget.mesh import Mesh
    from faceretarget.rig import Rig

    monkeypatch.setenv("FACERETARGET_CACHE", str(tmp_path / "cache"))
    rig = read_rig(data_dir / "arkit-face")
    c, s_ = np.cos(np.radians(17)), np.sin(np.radians(17))
    R = np.array([[1.0, 0.0, 0.0], [0.0, c, -s_], [0.0, s_, c]])
    m = rig.neutral
    nod = Rig(Mesh(m.vertices @ R.T, m.face_counts, m.face_indices, name="nod"), list(rig.names), rig.deltas @ R.T,
              unit=rig.unit, name="nod")
    paths = [write_glb(tmp_path / f"{n}.glb", r, np.zeros((1, r.n_shapes)), np.zeros(1))
             for n, r in (("upright", rig), ("nod", nod))]
    up, lines = load_character(paths[0]), []
    tipped = load_character(paths[1], log=lines.append)
    assert np.allclose(up.up, [0, 1, 0]) and up.front is not None and np.allclose(up.front, [0, 0, 1])
    deg = np.degrees(np.arccos(tipped.up @ (R @ [0.0, 1.0, 0.0])))
    assert deg < 17.0 - PITCH_TOLERANCE_DEG, deg                     # within the landmarker's reach of the truth
    assert any("looks" in ln and "down" in ln for ln in lines) and any("looking again" in ln for ln in lines)
    a, b = up.landmark_positions(), tipped.landmark_positions() @ R
    eoc = np.linalg.norm(a[36] - a[45])
    assert np.linalg.norm(a[:17] - b[:17], axis=1).mean() < 0.06 * eoc
    assert face_pitch_turn(up, PITCH_BIAS_DEG + PITCH_TOLERANCE_DEG - 0.5) is None and np.allclose(up.up, [0, 1, 0])


def test_a_face_wound_inside_out_is_found_and_shaped_as_outward(data_dir, tmp_path, monkeypatch):
    """A face mesh whose triangles wind inward (an inside-out export; a mirror whose winding was not turned),
    single-sided as glTF's default material is: the landmark search saw nothing from the front and found the
    face from behind, in the hollow of the mask, left and right swapped (every generated shape on the wrong
    side, 100 % off, while the closed lids and unfolded triangles read as right).  It is now drawn from both
    sides to be looked at and its normals taken outward: the same landmarks and shapes as the outward file's."""
    pytest.importorskip("mediapipe")
    from faceretarget.io import write_glb
    from faceretarget.mesh import Mesh
    from faceretarget.rig import Rig

    monkeypatch.setenv("FACERETARGET_CACHE", str(tmp_path / "cache"))
    rig = read_rig(data_dir / "arkit-face")
    m = rig.neutral
    starts = np.r_[0, np.cumsum(m.face_counts)[:-1]]
    idx = np.concatenate([m.face_indices[s0:s0 + c][::-1] for s0, c in zip(starts, m.face_counts, strict=True)])
    inside_out = Rig(Mesh(m.vertices, m.face_counts, idx, name="face"), list(rig.names), rig.deltas,
                     unit=rig.unit, name="face")
    assert not m.winds_inward() and inside_out.neutral.winds_inward()
    paths = [write_glb(tmp_path / f"{n}.glb", r, np.zeros((1, r.n_shapes)), np.zeros(1))
             for n, r in (("outward", rig), ("inward", inside_out))]
    lines: list[str] = []
    a, b = load_character(paths[0]), load_character(paths[1], log=lines.append)
    assert any("wind inward" in ln for ln in lines)
    pa, pb = a.landmark_positions(), b.landmark_positions()
    eoc = float(np.linalg.norm(pa[36] - pa[45]))
    assert np.linalg.norm(pa - pb, axis=1).max() < 0.01 * eoc            # swapped: an eye-corner distance off
    names = ["eyeBlinkLeft", "mouthSmileLeft", "jawOpen"]
    made = []
    for ch in (a, b):
        hidden = hide_shapes(ch)
        hidden.landmarks = ch.landmarks
        gen = generate_shapes(hidden, shapes=names)
        made.append(gen.apply())
    assert any("wind inward" in n for n in gen.notes)
    for n in names:
        da, db = shape_delta(made[0], n).astype(float), shape_delta(made[1], n).astype(float)
        mv = np.linalg.norm(da, axis=1) > 0.1 * np.linalg.norm(da, axis=1).max()
        assert np.sqrt(((db - da)[mv] ** 2).sum(1).mean() / (da[mv] ** 2).sum(1).mean()) < 0.03, n


def test_a_face_denser_than_generation_handles_is_told(data_dir, arkit_generated, monkeypatch):
    """A scan-dense face (74k vertices: 6 min, 5,319 triangles turned over at the mouth's corners) is told
    what to expect and what to do, before the wait and in the notes; a production head (arkit-face, 1,220
    face vertices) is not."""
    from faceretarget.characters import _generate

    ref, whole, _, _ = arkit_generated
    assert not any("decimated" in n for n in whole.notes)
    hidden = hide_shapes(read_character(data_dir / "arkit-face"))
    hidden.landmarks = ref.landmarks
    monkeypatch.setattr(_generate, "_DENSE_FACE", 1000)
    lines: list[str] = []
    gen = generate_shapes(hidden, shapes=["jawOpen"], progress=lines.append)
    said = [n for n in gen.notes if "decimated" in n]
    assert len(said) == 1 and "1,220 vertices in the face" in said[0] and "1k face vertices" in said[0], said
    assert any("takes minutes" in ln for ln in lines[:3])                 # before the wait
    lm = gen.apply().landmark_positions()
    assert np.abs(shape_delta(gen.apply(), "jawOpen")).max() > 0.1 * np.linalg.norm(lm[36] - lm[45])


def _mouth_sealed(ch):
    """A copy of the character whose mouth opening is zipped shut (a strip of triangles from the upper lip's
    edge to the lower's, corner to corner): lips that are one surface, as a scan's are."""
    import copy

    from faceretarget.mesh import Mesh
    from faceretarget.transfer import components

    out = copy.deepcopy(ch)
    m = out.meshes[out.landmarks.mesh]
    V, T = m.mesh.vertices, m.mesh.triangles()
    e = np.concatenate([T[:, [0, 1]], T[:, [1, 2]], T[:, [2, 0]]])
    _, inv, cnt = np.unique(np.sort(e, axis=1), axis=0, return_inverse=True, return_counts=True)
    border = e[cnt[inv.ravel()] == 1]                               # directed as their triangles wind
    lab = components(len(V), np.c_[border, border[:, :1]])
    lm = out.landmark_positions()
    ring = min((border[lab[border[:, 0]] == k] for k in np.unique(lab[border[:, 0]])),
               key=lambda b: np.linalg.norm(V[b[:, 0]].mean(axis=0) - lm[60:68].mean(axis=0)))
    nxt = dict(ring.tolist())
    loop = [int(ring[0, 0])]
    while nxt[loop[-1]] != loop[0]:
        loop.append(nxt[loop[-1]])
    loop = np.array(loop)
    k0, k1 = (int(np.argmin(np.linalg.norm(V[loop] - lm[i], axis=1))) for i in (60, 64))
    n = len(loop)
    A = loop[[(k0 + i) % n for i in range((k1 - k0) % n + 1)]]          # along the border's direction
    B = loop[[(k0 - i) % n for i in range((k0 - k1) % n + 1)]]          # against it, also corner to corner
    strip, i, j = [[A[1], A[0], B[1]]], 1, 1                            # A[0] = B[0], A[-1] = B[-1]: corners
    while i < len(A) - 2 or j < len(B) - 2:
        if j == len(B) - 2 or (i < len(A) - 2 and np.linalg.norm(V[A[i + 1]] - V[B[j]])
                               <= np.linalg.norm(V[A[i]] - V[B[j + 1]])):
            strip.append([A[i + 1], A[i], B[j]])
            i += 1
        else:
            strip.append([B[j], B[j + 1], A[i]])
            j += 1
    strip = np.array(strip + [[A[-1], A[-2], B[-2]]])
    m.mesh = Mesh(V, np.r_[m.mesh.face_counts, np.full(len(strip), 3)], np.r_[m.mesh.face_indices, strip.ravel()],
                  name=m.mesh.name)
    return out


def test_lips_that_are_one_surface_are_told(data_dir, arkit_generated):
    """A face whose lips are one surface (a scan's; no mouth opening between them) cannot part them: the mouth
    shapes stretch the surface across the mouth.  Generation says so and what to do; a face with an opening
    (arkit-face, its lips touching at rest) is not told."""
    ref, whole, _, _ = arkit_generated
    assert not any("one surface" in n for n in whole.notes)
    hidden = hide_shapes(read_character(data_dir / "arkit-face"))
    hidden.landmarks = ref.landmarks
    gen = generate_shapes(_mouth_sealed(hidden), shapes=["jawOpen"])
    said = [n for n in gen.notes if "one surface" in n]
    assert len(said) == 1 and "cut the lips apart" in said[0], gen.notes


def test_blinks_close_on_a_head_held_turned(data_dir):
    """arkit-face turned 25 degrees in its file, its landmarks given: its blinks stayed 32 % open and its
    left / right shapes were not made mirror images (no symmetry plane found along the file's axes); in the
    face's own frame the lids close as upright (2 %) and the pairs mirror."""
    from faceretarget.transfer import mirror_err_pct

    ref = load_character(data_dir / "arkit-face")
    hidden = hide_shapes(read_character(data_dir / "arkit-face"))
    hidden.landmarks = ref.landmarks
    turned, _ = _yawed(hidden, 25.0)
    turned.up, turned.front = np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0])
    gen = generate_shapes(turned, shapes=["eyeBlinkLeft", "eyeBlinkRight", "mouthSmileLeft", "mouthSmileRight"])
    drive = gen.apply()
    assert shape_metrics(drive)["blink_gap_pct"] <= 10.0
    assert mirror_err_pct(drive) is not None and mirror_err_pct(drive) <= 1.0
    assert any("turned 25.0 degrees" in n for n in drive.notes + gen.notes)


def test_mouth_close_keeps_the_skin_out_of_the_lower_teeth():
    """The demo face bo (no data needed): its lower teeth, a bar riding the chin's rigid motion, drop further
    than the floor of the mouth behind them, so ``jawOpen + mouthClose`` put 2 vertices of that skin inside
    them; the skin is pushed out of the posed teeth while ``jawOpen`` and ``mouthClose`` are made, with no
    triangle turned over."""
    from faceretarget.datasets import make_demo_character
    from faceretarget.io import character_from_rig
    from faceretarget.transfer import lips_in_teeth

    rig = make_demo_character("bo")
    ref = load_character(character_from_rig(rig))
    hidden = hide_shapes(character_from_rig(rig))
    hidden.landmarks = ref.landmarks
    gen = generate_shapes(hidden, shapes=["jawOpen", "mouthClose"])
    drive = gen.apply()
    assert lips_in_teeth(drive) == 0
    m = shape_metrics(drive)
    assert m["inverted_triangles"] == 0 and m["lip_gap_pct"] <= 1.0


# slow: generates shapes from the arkit-face USD asset and measures every rim vertex (~8 s)
def test_blink_closes_the_whole_rim_of_the_eye(data_dir, tmp_path):
    """The arkit-face as a USD asset, its landmarks found automatically (its lid points land close together on
    this low-poly face without eyeballs): pinned only at those points the lids stayed open (72-88 % of the rim's
    gap); the rim of each eye opening is pinned shut, and the metric measures the rim."""
    pytest.importorskip("pxr")
    pytest.importorskip("mediapipe")
    from faceretarget.character import character_frame
    from faceretarget.io import write_usd
    from faceretarget.transfer import blink_gap_pct, lid_margins
    from faceretarget.transfer._metrics import _rim_gap_pct

    rig = read_rig(data_dir / "arkit-face")
    asset = write_usd(tmp_path / "arkit.usda", rig, np.zeros((1, rig.n_shapes)), np.zeros(1))
    ch = hide_shapes(read_character(asset))
    ch.path = None
    gen = generate_shapes(ch, shapes="eyeBlinkLeft,eyeBlinkRight")
    new = gen.apply()
    m = new.meshes[new.landmarks.mesh]
    T = m.mesh.triangles()
    rims = lid_margins(m.mesh.vertices.astype(float), T, new.landmark_positions(), character_frame(new))
    assert len(rims) == 2 and all(r.upper.sum() >= 4 and (~r.upper).sum() >= 4 for r in rims)
    gaps = [_rim_gap_pct(new, side, shape_delta(new, f"eyeBlink{side}").astype(float)) for side in ("Left", "Right")]
    assert max(gaps) <= 10.0, gaps
    assert blink_gap_pct(new)[0] == pytest.approx(max(gaps))


# slow: the CLI generates a whole ARKit set and writes/reads an OBJ rig folder (~13 s)
def test_cli_obj_folder_round_trip(data_dir, tmp_path):
    out = tmp_path / "gen"
    rc = main(["-q", "character", "shapes", str(data_dir / "arkit-face"), "--shapes", "eyeBlinkLeft,jawOpen",
               "--replace", "--out", str(out)])
    assert rc == 0
    rig = read_rig(out)
    assert sorted(rig.names) == sorted(["eyeBlinkLeft", "jawOpen"] + [
        normalize_name(n) for n in read_character(data_dir / "arkit-face").meshes[0].shape_names
        if normalize_name(n) not in ("eyeBlinkLeft", "jawOpen")])
    gen = generate_shapes(data_dir / "arkit-face", shapes="eyeBlinkLeft,jawOpen", replace=True)
    k = rig.names.index("jawOpen")
    assert np.abs(rig.deltas[k] * rig.mm_per_unit / 1000.0 - gen.added["arkit-face"]["jawOpen"]).max() < 1e-6
    assert (out / "landmarks68.txt").is_file() and rig.landmarks is not None and len(rig.landmarks) == 68


def test_cli_bad_inputs(data_dir, tmp_path, capsys):
    src = str(data_dir / "arkit-face")
    assert main(["character", "shapes", src, "--shapes", "tongueOut", "--out", str(tmp_path / "a")]) == 2
    assert "tongueOut" in capsys.readouterr().err
    assert main(["character", "shapes", src, "--shapes", "smile", "--out", str(tmp_path / "b")]) == 2
    assert "not an ARKit shape name" in capsys.readouterr().err
    empty = tmp_path / "rig"
    empty.mkdir()
    rig = read_rig(data_dir / "arkit-face")
    from faceretarget.io import write_obj

    write_obj(empty / "neutral.obj", rig.neutral)
    (empty / "landmarks68.txt").write_text(" ".join(map(str, rig.landmarks)))
    assert main(["character", "shapes", src, "--template", str(empty), "--out", str(tmp_path / "c")]) == 2
    assert "no face shapes" in capsys.readouterr().err
    assert main(["character", "shapes", str(tmp_path / "missing"), "--out", str(tmp_path / "d")]) == 2
    assert "not found" in capsys.readouterr().err
    # every shape asked is its own (kept): one line before any work, instead of an API message after it
    assert main(["character", "shapes", src, "--shapes", "jawOpen,eyeBlinkLeft", "--out", str(tmp_path / "d.glb")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "has all 2 of the shapes asked" in err[0] and "--replace" in err[0], err
    try:
        from faceretarget.io import write_character_shapes  # noqa: F401
    except ImportError:
        assert main(["character", "shapes", src, "--out", str(tmp_path / "e.glb")]) == 2
        assert "write_character_shapes" in capsys.readouterr().err
    assert not any((tmp_path / n).exists() for n in ("a", "b", "c", "d", "d.glb", "e", "e.glb"))


def test_no_face_found(tmp_path, capsys):
    """A mesh with no face: no shapes, and a message naming --landmarks."""
    from faceretarget.io import write_obj
    from faceretarget.mesh import Mesh

    box = tmp_path / "box"
    box.mkdir()
    v = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float) * 0.2
    f = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]
    write_obj(box / "neutral.obj", Mesh(v, np.full(6, 4), np.array(f).ravel()))
    assert main(["character", "shapes", str(box), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "no face found" in err and "--landmarks" in err
