"""The pick-and-place scene both planners of benches/pick_place_peers.py share (numbers only: it
imports neither profrobot nor mplib). Metres, radians; pybullet_data's Panda at the origin."""

TABLE_TOP = 0.2
TABLE = ((0.5, 0.0, TABLE_TOP / 2), (0.3, 0.6, TABLE_TOP / 2))          # centre, half sizes
WALL = ((0.45, 0.0, TABLE_TOP + 0.125), (0.12, 0.02, 0.125))
HOVER = 0.002                                                            # the mug 2 mm above the table
MUG = ((0.45, -0.3, TABLE_TOP + 0.05 + HOVER), 0.025, 0.05)               # centre, radius, half height
PICK, PLACE = (0.45, -0.3), (0.45, 0.3)
DOWN_QUAT = (0.0, 1.0, 0.0, 0.0)         # (w, x, y, z): the grasp target's z pointing down
HOME = (0.0, 0.0, 0.0, -1.57079, 0.0, 1.57079, 0.7853, 0.04, 0.04)
ARM_V = tuple(v * 0.5 for v in (2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61))
ARM_A = tuple(a * 0.3 for a in (15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0))
STAGES = ("pre-grasp", "approach", "close", "lift", "carry", "place", "open", "retreat")
TCP = 0.105                               # panda_hand → panda_grasptarget


def grasp_z() -> float:
    """The grasp target's height: 3 cm below the mug's top."""
    return MUG[0][2] + MUG[2] - 0.03
