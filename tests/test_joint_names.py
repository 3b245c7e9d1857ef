"""Skeleton joints found by role whatever the exporter's namespace, prefix or suffix."""

import pytest

from faceretarget.names import find_joints, joint_role

CASES = {
    "head": ["Head", "head", "mixamorig:Head", "mixamorig1:Head", "Bip01 Head", "Bip001_Head", "J_Bip_C_Head",
             "DEF-spine.006", "CC_Base_Head", "c_head.x", "Head_M", "head_JNT", "Rocketbox:Bip01 Head"],
    "neck": ["Neck", "neck_01", "Neck1", "mixamorig:Neck", "Bip01 Neck", "J_Bip_C_Neck", "DEF-neck", "CC_Base_Neck"],
    "jaw": ["Jaw", "CC_Base_JawRoot", "lowerJaw", "mixamorig:Jaw"],
    "leftEye": ["LeftEye", "mixamorig:LeftEye", "J_Adj_L_FaceEye", "CC_Base_L_Eye", "eye.L", "Eye_L", "EyeL", "lEye",
                "Bip01 L Eye", "FaceEye_L", "eye_left"],
    "rightEye": ["RightEye", "J_Adj_R_FaceEye", "CC_Base_R_Eye", "eye.R", "Eye_R", "rEye", "Right_Eye"],
    None: ["HeadTop_End", "Head_end", "HeadEnd", "Bip01 Head Nub", "LeftEyeLid", "Hips", "RightToeEnd", "Bone",
           "RootNode", "LowerLeg.L", "HeadTwist", "", "Chest"],
}


@pytest.mark.parametrize("role,name", [(r, n) for r, names in CASES.items() for n in names])
def test_joint_role(role, name):
    assert joint_role(name) == role


def test_find_joints_prefers_the_root_side_and_a_neck_above_the_head():
    names = ["Hips", "Spine", "Neck", "Neck1", "Head", "HeadTop_End", "LeftEye", "RightEye", "LeftHand"]
    parents = [-1, 0, 1, 2, 3, 4, 4, 4, 1]
    assert find_joints(names, parents) == {"neck": 2, "head": 4, "leftEye": 6, "rightEye": 7}
    # a "neck" that is not an ancestor of the head is not the neck
    assert find_joints(["Root", "Neck", "Head"], [-1, 0, 0]) == {"head": 2}
