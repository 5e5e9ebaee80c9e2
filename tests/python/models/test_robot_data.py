"""Robots as data: ``marionette robot import`` / ``check`` on arms of example-robot-data that the
project does not ship, and the one-line answers to broken robot folders."""

from __future__ import annotations

import shutil
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from marionette import robots
from marionette.models.robot_check import check_robot
from marionette.models.robot_import import RobotImportError, import_robot
from marionette.schemas import DataFileError

ERD = robots.example_robot_data_dir()


def _errors(findings):
    return [str(f) for f in findings if f.level == "error"]


@pytest.fixture
def on_path(tmp_path, monkeypatch):
    """A robot folder root on $MARIONETTE_ROBOT_PATH."""
    root = tmp_path / "robots"
    root.mkdir()
    monkeypatch.setenv(robots.ROBOT_PATH_VARIABLE, str(root))
    return root


@pytest.mark.slow
@pytest.mark.parametrize(
    ("urdf", "srdf"),
    [
        ("panda_description/urdf/panda.urdf", "panda_description/srdf/panda.srdf"),
        ("ur_description/urdf/ur5_robot.urdf", "ur_description/srdf/ur5.srdf"),
        ("xarm_description/urdf/xarm7.urdf", "xarm_description/srdf/xarm7.srdf"),
        ("kinova_description/robots/kinova.urdf", "kinova_description/srdf/kinova.srdf"),
    ],
)
def test_an_imported_arm_checks_and_compiles(on_path, build_dir, urdf, srdf):
    name = Path(urdf).stem.replace("_robot", "")
    folder = on_path / name
    notes = import_robot(ERD / urdf, name, folder, ERD / srdf)
    assert notes
    assert not _errors(check_robot(folder)), check_robot(folder)
    assert (folder / f"{name}.xml").is_file()
    # Mimic joints became fixed: Pinocchio's model has exactly the URDF's movable non-mimics.
    root = ET.parse(folder / f"{name}.urdf").getroot()
    movable = [
        j
        for j in root.iter("joint")
        if j.get("type") in ("revolute", "prismatic", "continuous") and j.find("mimic") is None
    ]
    model, _ = robots.load_pinocchio(name, with_collision=False)
    assert model.njoints - 1 == len(movable)
    assert name in robots.robot_names()


@pytest.mark.slow
def test_a_dae_only_arm_gets_converted_collision_meshes(on_path):
    folder = on_path / "kinova"
    import_robot(ERD / "kinova_description/robots/kinova.urdf", "kinova", folder)
    assert not _errors(check_robot(folder))
    converted = list((folder / "converted_meshes").rglob("*.stl"))
    assert converted, "no DAE converted to STL"
    mjcf = (folder / "kinova.xml").read_text()
    assert "converted_meshes" in mjcf and ".dae" not in mjcf


@pytest.fixture
def ur10_copy(on_path):
    folder = on_path / "ur10"
    shutil.copytree(robots.robot("ur10").directory, folder, symlinks=True)
    return folder


def _edit(folder: Path, old: str, new: str) -> None:
    path = folder / "robot.yaml"
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new, 1))


@pytest.mark.parametrize(
    ("old", "new", "expected"),
    [
        ("reference_posture: home", "refrence_posture: home", "did you mean 'reference_posture'"),
        ("base: fixed", "base: 3", "3 is not one of"),
        ("link: gripper_link", "link: gripper_lnk", "'gripper_lnk' is not a link"),
        ("joint: finger_joint", "joint: finger_jiont", "'finger_jiont' is not a movable joint"),
        ("closed_position: 0.04", "closed_position: 0.4", "outside finger_joint's limits"),
        ("link: gripper_link", "link: finger_left_link", "moves with the finger joint"),
        ("reference_posture: home", "reference_posture: away", "no group_state 'away'"),
        ("- {joints: finger_", "- {joints: fingerless_", "no entry matches joint 'finger_joint'"),
    ],
)
def test_each_mistake_is_one_finding_naming_what_to_fix(ur10_copy, old, new, expected):
    _edit(ur10_copy, old, new)
    errors = _errors(check_robot(ur10_copy, build=False))
    assert len(errors) == 1 and expected in errors[0], errors
    assert "\n" not in errors[0]


def test_a_yaml_syntax_error_names_the_line(ur10_copy):
    path = ur10_copy / "robot.yaml"
    lines = path.read_text().splitlines()
    lines[10] = lines[10] + ": ]"  # a mapping value where a scalar ends
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(DataFileError, match=r"robot\.yaml:1[01]: not valid YAML"):
        robots.robot(ur10_copy)


def test_a_movable_mimic_joint_is_refused_with_the_fix(on_path):
    folder = on_path / "panda"
    import_robot(
        ERD / "panda_description/urdf/panda.urdf",
        "panda",
        folder,
        ERD / "panda_description/srdf/panda.srdf",
    )
    urdf = folder / "panda.urdf"
    urdf.write_text(
        urdf.read_text().replace(
            '<joint name="panda_finger_joint2" type="fixed">',
            '<joint name="panda_finger_joint2" type="prismatic">',
        )
    )
    (error,) = _errors(check_robot(folder, build=False))
    assert "panda_finger_joint2" in error and 'make it type="fixed"' in error


def _erd_described_robots() -> list[tuple[str, str]]:
    """(URDF, SRDF) of example-robot-data's robots whose SRDF names an end effector and whose
    URDF, beside it, has at most 10 movable joints (arms and small robots): what a user brings
    with ``marionette robot import URDF --srdf SRDF``."""
    out = []
    for srdf in sorted(ERD.glob("*/srdf/*.srdf")):
        urdfs = sorted(srdf.parents[1].glob(f"*/{srdf.stem}.urdf"))
        if not urdfs or "<end_effector" not in srdf.read_text():
            continue
        urdf = ET.parse(urdfs[0]).getroot()
        movable = [j for j in urdf.iter("joint") if j.get("type") in ("revolute", "prismatic")]
        if len(movable) <= 10:
            out.append((str(urdfs[0].relative_to(ERD)), str(srdf.relative_to(ERD))))
    return out


@pytest.mark.slow
@pytest.mark.parametrize(("urdf", "srdf"), _erd_described_robots())
def test_an_imported_srdf_gives_a_reference_posture_free_of_self_collision(on_path, urdf, srdf):
    """The import keeps an SRDF's own postures only when they pass the check (limits and
    self-collision, the adjacent links it lacks disabled), whatever the SRDF declares."""
    name = Path(urdf).stem.replace("-", "_")
    folder = on_path / name
    import_robot(ERD / urdf, name, folder, ERD / srdf)
    assert not _errors(check_robot(folder, build=False))


@pytest.mark.slow
def test_a_fixed_joint_named_as_a_link_is_renamed_by_the_import_and_refused_by_the_check(
    on_path, tmp_path
):
    """Every fixed joint of an arm in turn takes its child link's name (a URDF may do so): the
    check refuses it in one line, the import renames it and the folder then checks."""
    source = ET.parse(ERD / "panda_description/urdf/panda.urdf").getroot()
    fixed = [j.get("name") for j in source.iter("joint") if j.get("type") == "fixed"]
    assert fixed
    for k, joint in enumerate(fixed):
        root = ET.parse(ERD / "panda_description/urdf/panda.urdf").getroot()
        j = next(j for j in root.iter("joint") if j.get("name") == joint)
        link = j.find("child").get("link")
        j.set("name", link)
        urdf = tmp_path / f"panda{k}.urdf"
        ET.ElementTree(root).write(urdf)
        folder = on_path / f"arm{k}"
        notes = import_robot(urdf, f"arm{k}", folder)
        assert any(f"renamed {link}_joint" in n for n in notes), notes
        assert not _errors(check_robot(folder, build=False))
        imported = folder / f"arm{k}.urdf"
        imported.write_text(imported.read_text().replace(f'"{link}_joint"', f'"{link}"'))
        (error,) = _errors(check_robot(folder, build=False))
        assert f"joint {link!r} has the name of a link" in error


@pytest.mark.parametrize(
    ("insert", "refused"),
    [
        ('<xacro:property name="d" value="0.1"/>', True),
        (
            '<link name="extra"><visual><geometry><box size="${d} 1 1"/></geometry>'
            "</visual></link>",
            True,
        ),
        ('<!-- <xacro:property name="d" value="0.1"/> -->', False),
    ],
)
def test_only_xacro_left_outside_comments_is_refused(on_path, tmp_path, insert, refused):
    """Expanded URDFs often keep xacro in comments (example-robot-data's bolt, finger, TALOS):
    they import; an element or a ${...} value xacro did not expand is refused in one line."""
    text = (ERD / "ur_description/urdf/ur5_robot.urdf").read_text()
    head, sep, tail = text.partition(">\n")  # after the <?xml ...?> line
    start = tail.index("<robot") + len("<robot")
    if "xmlns:xacro" not in tail:
        tail = tail[:start] + ' xmlns:xacro="http://www.ros.org/wiki/xacro"' + tail[start:]
    end = tail.index(">", start) + 1
    urdf = tmp_path / "arm.urdf"
    urdf.write_text(head + sep + tail[:end] + "\n" + insert + tail[end:])
    if refused:
        with pytest.raises(RobotImportError, match="a xacro file; expand it first"):
            import_robot(urdf, "arm", on_path / "arm")
    else:
        import_robot(urdf, "arm", on_path / "arm")


def _jaws(open_gap: float, closed: bool = True):
    """Two 2 x 2 x 6 cm jaws on a 6 x 2 x 2 cm palm, ``open_gap`` apart (0: a solid block)."""
    import trimesh

    w = (0.06 - open_gap) / 2
    parts = [
        trimesh.creation.box(
            (0.06, 0.02, 0.02), trimesh.transformations.translation_matrix((0, 0, 0.01))
        )
    ]
    for side in (-1, 1):
        centre = (side * (0.03 - w / 2), 0, 0.05)
        parts.append(
            trimesh.creation.box(
                (w, 0.02, 0.06), trimesh.transformations.translation_matrix(centre)
            )
        )
    mesh = trimesh.util.concatenate(parts)
    if not closed:
        mesh.update_faces(np.arange(len(mesh.faces)) != 0)
    return mesh


@pytest.mark.parametrize(
    ("gap", "closed", "noted"), [(0.0, True, False), (0.04, True, True), (0.04, False, True)]
)
def test_a_hand_mesh_far_from_convex_is_noted(ur10_copy, gap, closed, noted):
    """MuJoCo collides a mesh as its convex hull: jaws whose hull fills the gap between them
    push objects away. The check notes a hand link's collision mesh filling < 80 % of its hull
    (closed or not); a solid block passes."""
    stl = ur10_copy / "jaws.stl"
    _jaws(gap, closed).export(stl)
    urdf = ur10_copy / "ur10.urdf"
    root = ET.parse(urdf).getroot()
    link = next(k for k in root.iter("link") if k.get("name") == "finger_left_link")
    for c in link.findall("collision"):
        link.remove(c)
    collision = ET.SubElement(link, "collision")
    ET.SubElement(ET.SubElement(collision, "geometry"), "mesh", filename=str(stl))
    ET.ElementTree(root).write(urdf)
    findings = check_robot(ur10_copy, build=False)
    assert not _errors(findings)
    notes = [str(f) for f in findings if "convex hull" in f.message]
    assert len(notes) == noted and (not noted or "link finger_left_link" in notes[0]), notes


def test_an_srdf_end_effector_on_a_jaw_puts_the_gripper_on_the_palm(on_path, tmp_path):
    """An SRDF may name a moving jaw as its end effector (example-robot-data's z1): each finger
    link of an arm in turn, moved by a joint its SRDF's arm group leaves out, gives a gripper on
    the link the jaw is mounted on, with that joint; the folder checks."""
    srdf = (ERD / "panda_description/srdf/panda.srdf").read_text()
    sroot = ET.fromstring(srdf)
    ee = sroot.find("end_effector").get("parent_link")
    arm = max(({j.get("name") for j in g.findall("joint")} for g in sroot.iter("group")), key=len)
    urdf = ET.parse(ERD / "panda_description/urdf/panda.urdf").getroot()
    jaws = [
        j
        for j in urdf.iter("joint")
        if j.get("type") in ("revolute", "prismatic")
        and j.find("mimic") is None
        and j.get("name") not in arm
    ]
    assert jaws
    for k, joint in enumerate(jaws):
        link = joint.find("child").get("link")
        moved = tmp_path / f"arm{k}.srdf"
        moved.write_text(srdf.replace(f'parent_link="{ee}"', f'parent_link="{link}"'))
        folder = on_path / f"arm{k}"
        import_robot(ERD / "panda_description/urdf/panda.urdf", f"arm{k}", folder, moved)
        (gripper,) = robots.semantics(folder).grippers
        assert gripper.link == joint.find("parent").get("link")
        assert gripper.joint == joint.get("name")
        assert not _errors(check_robot(folder, build=False))


def _imported_urdf(urdf: str):
    """example-robot-data's ``urdf`` as the import leaves it (mimic joints fixed), parsed."""
    from marionette.models.robot_import import _fix_mimics
    from marionette.models.urdf import parse_urdf
    from marionette.models.xml_util import indent_and_serialize

    root = ET.parse(ERD / urdf).getroot()
    _fix_mimics(root)
    return parse_urdf(indent_and_serialize(root, "test"))


@pytest.mark.parametrize(
    ("urdf", "joint", "closed"),
    [  # from each hand's documentation: the Z1's jaw is shut at 0, its upper limit
        ("z1_description/urdf/z1.urdf", "jointGripper", "upper"),
        ("panda_description/urdf/panda.urdf", "panda_finger_joint1", "lower"),
        ("so_arm_description/urdf/so101.urdf", "gripper", "lower"),
        ("so_arm_description/urdf/so100.urdf", "gripper", "lower"),
        # a linkage of mimic joints the URDF made fixed; models/talos closes it at -1.0
        ("talos_data/robots/talos_left_arm.urdf", "gripper_left_joint", "lower"),
    ],
)
def test_the_import_guesses_which_limit_closes_a_jaw_from_the_hand(urdf, joint, closed):
    """The import's closed position is near the limit where the jaw folds onto the rest of the
    hand, whichever it is (the Z1's jaw closes towards its upper limit, the others towards their
    lower one), its mimic joints following it."""
    from marionette.models.robot_import import _finger
    from marionette.models.urdf import read_urdf

    u = read_urdf(ERD / urdf)
    notes: list[str] = []
    finger = _finger(u, u.joints[joint], Path(urdf), notes, 0)
    lower, upper = u.joints[joint].lower, u.joints[joint].upper
    near_closed = {"lower": lower, "upper": upper}[closed]
    near_open = {"lower": upper, "upper": lower}[closed]
    assert abs(finger["closed_position"] - near_closed) < 0.1 * (upper - lower), notes
    assert abs(finger["open_position"] - near_open) < 0.1 * (upper - lower), notes
    assert f"closed near its {closed} limit" in notes[0]


@pytest.mark.parametrize("seed", range(6))
def test_a_hinged_jaw_closes_towards_the_fixed_one_whatever_its_axis(tmp_path, seed):
    """A 2.4 cm wide palm with a fixed jaw and a jaw hinged on its edge, the hinge's axis and
    limits drawn at random (either sign, the closed end on either limit): the guess is the limit
    where the jaws lie side by side, 1 mm apart (closed); at the other the jaw stands 60-120 deg
    open."""
    from marionette.models.jaw import closing_limit
    from marionette.models.urdf import parse_urdf

    rng = np.random.default_rng(seed)
    sign = rng.choice([-1.0, 1.0])
    opening = np.radians(rng.uniform(60, 120))
    # The jaw hangs along -z from a hinge at y = 6 mm about x; turning it about +x by a positive
    # angle swings its tip towards +y, away from the fixed jaw (y in [-10, 0] mm).
    lower, upper = (0.0, opening) if sign > 0 else (-opening, 0.0)
    closed = "lower" if sign > 0 else "upper"
    box = '<collision><origin xyz="{}"/><geometry><box size="{}"/></geometry></collision>'
    text = f"""<robot name="hand">
      <link name="palm">{box.format("0 0 0.01", "0.03 0.024 0.02")}
        {box.format("0 -0.005 -0.03", "0.02 0.01 0.06")}</link>
      <link name="jaw">{box.format("0 0 -0.03", "0.02 0.01 0.06")}</link>
      <joint name="hinge" type="revolute"><parent link="palm"/><child link="jaw"/>
        <origin xyz="0 0.006 0"/><axis xyz="{sign} 0 0"/>
        <limit lower="{lower}" upper="{upper}" effort="1" velocity="1"/></joint>
    </robot>"""
    urdf = parse_urdf(text)
    assert closing_limit(urdf, urdf.joints["hinge"], 0.025).closed == closed


def test_an_srdf_gripper_gives_the_gripper_its_link_frame_and_clearance(on_path):
    """example-robot-data's ur3_gripper.srdf declares HPP's <gripper> (link tool0, a frame 5.5 cm
    out of it, clearance 3 cm) over two fixed fingers: the import takes it, its frame's x along
    the fingers (out of tool0) and its y across them (along the line joining them)."""
    folder = on_path / "ur3"
    notes = import_robot(
        ERD / "ur_description/urdf/ur3_gripper.urdf",
        "ur3",
        folder,
        ERD / "ur_description/srdf/ur3_gripper.srdf",
    )
    (gripper,) = robots.robot(folder).data["grippers"]
    assert gripper["link"] == "tool0" and gripper["clearance"] == 0.03, notes
    assert "joint" not in gripper
    import pinocchio as pin

    X = pin.XYZQUATToSE3(np.r_[gripper["pose"]["xyz"], gripper["pose"]["xyzw"]])
    u = _imported_urdf("ur_description/urdf/ur3_gripper.urdf")
    fingers = [g.X_LG[:3, 3] for g in u.links["tool0"].collisions if g.size[2] >= 0.05]
    assert len(fingers) == 2
    across = (fingers[1] - fingers[0]) / np.linalg.norm(fingers[1] - fingers[0])
    middle = (fingers[0] + fingers[1]) / 2
    assert abs(X.rotation[:, 1] @ across) > 0.999  # y across the fingers
    assert X.rotation[:, 0] @ middle / np.linalg.norm(middle) > 0.999  # x out along them
    assert np.linalg.norm(np.cross(X.translation, middle)) < 1e-9  # the origin between them
    assert not _errors(check_robot(folder, build=False))


def test_jaws_beside_the_gripper_link_are_hand_links(on_path):
    """example-robot-data's SO-101 (no SRDF) carries its gripper frame on a bodiless link fixed
    to the fixed jaw's link, beside the moving jaw: both jaws are hand links (the check notes
    their meshes filling < 80 % of their hulls, the MJCF gives them the hand's class)."""
    folder = on_path / "so101"
    import_robot(ERD / "so_arm_description/urdf/so101.urdf", "so101", folder)
    (gripper,) = robots.robot(folder).data["grippers"]
    findings = check_robot(folder, build=False)
    assert not _errors(findings)
    noted = {f.where.rsplit("link ", 1)[-1] for f in findings if "convex hull" in f.message}
    assert {"gripper_link", "moving_jaw_so101_v1_link"} <= noted, findings
    from marionette.models.mjcf import hand_links
    from marionette.models.urdf import parse_urdf

    desc = robots.robot(folder)
    hands = hand_links(desc, parse_urdf(desc.urdf.read_text()))
    assert {gripper["link"], "gripper_link", "moving_jaw_so101_v1_link"} <= hands


def _arm_with_hand(tmp_path: Path, jaw_range: float, jaw_collision: bool = True) -> Path:
    """A 2-joint arm ending in a palm and a jaw hinged on it (range ``jaw_range`` rad), its
    deepest link; no SRDF."""
    box = '<collision><origin xyz="{}"/><geometry><box size="{}"/></geometry></collision>'
    jaw = box.format("0 0 -0.03", "0.02 0.01 0.06") if jaw_collision else ""
    inertial = (
        '<inertial><mass value="0.1"/>'
        '<inertia ixx="1e-4" iyy="1e-4" izz="1e-4" ixy="0" ixz="0" iyz="0"/></inertial>'
    )
    text = f"""<robot name="arm">
      <link name="base">{box.format("0 0 0.05", "0.1 0.1 0.1")}</link>
      <link name="upper">{inertial}{box.format("0 0 0.15", "0.04 0.04 0.2")}</link>
      <link name="forearm">{inertial}{box.format("0.15 0 0", "0.2 0.04 0.04")}</link>
      <link name="palm">{inertial}{box.format("0 0 0.01", "0.03 0.024 0.02")}
        {box.format("0 -0.005 -0.03", "0.02 0.01 0.06")}</link>
      <link name="jaw">{inertial}{jaw}</link>
      <joint name="pan" type="revolute"><parent link="base"/><child link="upper"/>
        <origin xyz="0 0 0.12"/><axis xyz="0 0 1"/>
        <limit lower="-3" upper="3" effort="10" velocity="1"/></joint>
      <joint name="lift" type="revolute"><parent link="upper"/><child link="forearm"/>
        <origin xyz="0 0 0.3"/><axis xyz="0 1 0"/>
        <limit lower="-2" upper="2" effort="10" velocity="1"/></joint>
      <joint name="wrist" type="fixed"><parent link="forearm"/><child link="palm"/>
        <origin xyz="0.3 0 0"/></joint>
      <joint name="hinge" type="revolute"><parent link="palm"/><child link="jaw"/>
        <origin xyz="0 0.006 0"/><axis xyz="1 0 0"/>
        <limit lower="0" upper="{jaw_range}" effort="1" velocity="1"/></joint>
    </robot>"""
    urdf = tmp_path / "arm.urdf"
    urdf.write_text(text)
    return urdf


@pytest.mark.parametrize(("jaw_range", "jaw"), [(1.5, True), (2 * np.pi, False)])
def test_without_srdf_a_deepest_link_moved_by_a_jaw_puts_the_gripper_on_the_palm(
    on_path, tmp_path, jaw_range, jaw
):
    """Without an SRDF the gripper's link is the deepest one; when that is a jaw (the chain's
    last movable joint, turning less than half a turn: example-robot-data's SO-100), the
    gripper goes on the link the jaw is mounted on, with that joint, and the folder checks. A
    last joint turning a full turn is a wrist: the gripper stays on its link, no finger."""
    folder = on_path / "arm"
    import_robot(_arm_with_hand(tmp_path, jaw_range), "arm", folder)
    (gripper,) = robots.semantics(folder).grippers
    assert (gripper.link, gripper.joint) == (("palm", "hinge") if jaw else ("jaw", None))
    assert not _errors(check_robot(folder, build=False))


def test_a_jaw_without_collision_geometry_is_refused(on_path, tmp_path):
    """A finger joint moving links with no <collision> (example-robot-data's SO-100 hand): in
    MuJoCo the jaw passes through the object. The check says so in one line."""
    folder = on_path / "arm"
    import_robot(_arm_with_hand(tmp_path, 1.5, jaw_collision=False), "arm", folder)
    (error,) = _errors(check_robot(folder, build=False))
    assert "link jaw: no <collision> on the links finger joint 'hinge' moves" in error


@pytest.mark.slow
def test_a_link_named_as_a_movable_joint_is_renamed_by_the_import_and_in_its_srdf(
    on_path, tmp_path
):
    """A link may carry its joint's name (example-robot-data's SO-100: joint and link
    'gripper'); Pinocchio frames are looked up by name. The import renames the link (the joint
    keeps its name, which the servos and postures use), in the URDF and in the given SRDF's
    collision pairs, and the folder checks."""
    source = (ERD / "panda_description/urdf/panda.urdf").read_text()
    urdf = tmp_path / "panda.urdf"
    urdf.write_text(source.replace('"panda_link4"', '"panda_joint4"'))
    srdf = tmp_path / "panda.srdf"
    srdf.write_text(
        (ERD / "panda_description/srdf/panda.srdf")
        .read_text()
        .replace('"panda_link4"', '"panda_joint4"')
    )
    folder = on_path / "arm"
    notes = import_robot(urdf, "arm", folder, srdf)
    assert any("renamed panda_joint4_link" in n for n in notes), notes
    assert "panda_joint4_link" in (folder / "arm.srdf").read_text()
    assert not _errors(check_robot(folder, build=False))
