"""Build the constraint graph from grippers, objects (handles, contact surfaces) and rules.

The recursion is HPP's ``ConstraintGraphFactory`` (thesis §3.4.2): a state is a set of grasps
(one handle or none per gripper); starting from "free", every available (gripper, handle) pair
adds a grasp, giving a new state, a grasp transition and its reverse release transition; every
state gets a loop transition that keeps its grasps.  Pruning rules (HPP ``Rule``: regular
expressions on the gripper -> handle assignment, first matching rule decides) drop the states
that are always in collision; for the plank of §3.4.2, 25 gripper x handle combinations become
17 states.

Per state, constraints: each grasp (explicit when the handle is on a free-flying object and
the mask is 6-D), and the placement of each object not grasped.  Foliation (what a transition
keeps constant, its parametrised constraints): grasp complements and placement complements.
A grasp transition on an object lying on a surface goes through three waypoint states
(fig. 3.4): pre-grasp (gripper ``clearance`` back along the approach axis, object placed),
intersection (grasped and placed), pre-placement (grasped, object lifted by
``preplacement_distance``).  The first two sub-edges lie in the source state (the object stays
on the table), the last two in the destination state (the object moves with the gripper).
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import pinocchio as pin

from marionette.planning.constraints import (
    Constraint,
    ExplicitConstraint,
    ExplicitRelativePose,
    LockedJoint,
    Placement,
    PlacementComplement,
    RelativeTransformation,
)
from marionette.planning.graph import (
    ConstraintGraph,
    Edge,
    GraphError,
    LevelSetEdge,
    State,
    WaypointEdge,
)
from marionette.planning.problem import ManipulationProblem
from marionette.planning.projector import LineSearch

AnyConstraint = Constraint | ExplicitConstraint


@dataclasses.dataclass
class Rule:
    """HPP rule: grippers[i] (regex) holds handles[i] (regex, "" = nothing) -> allowed = link."""

    grippers: list[str]
    handles: list[str]
    link: bool = False


class GraspRules:
    """Grasp-set validation by an ordered list of :class:`Rule` (HPP ``Rules``).

    The first rule that applies decides; with rules but none applying, the set is refused
    (HPP's default), so a list usually ends with ``Rule([".*"], [".*"], True)``.
    """

    def __init__(self, grippers: Sequence[str], handles: Sequence[str], rules: Sequence[Rule]):
        self.handles = tuple(handles)
        self.rules = []
        for r in rules:
            if len(r.grippers) != len(r.handles):
                raise GraphError(f"rule {r}: as many gripper patterns as handle patterns")
            per_gripper: list[re.Pattern | None] = [None] * len(grippers)
            for gp, hp in zip(r.grippers, r.handles):
                grc = re.compile(gp if gp else "^$")
                for i, g in enumerate(grippers):
                    if grc.fullmatch(g):
                        if per_gripper[i] is not None:
                            raise GraphError(f"rule {r}: gripper {g} matched twice")
                        per_gripper[i] = re.compile(hp if hp else "^$")
            self.rules.append((per_gripper, r.link))

    def _handle_name(self, handle: int | None) -> str:
        return "" if handle is None else self.handles[handle]

    def __call__(self, grasps: tuple[int | None, ...]) -> bool:
        if not self.rules:
            return True
        for per_gripper, link in self.rules:
            if all(
                p is None or p.fullmatch(self._handle_name(grasps[i]))
                for i, p in enumerate(per_gripper)
            ):
                return link
        return False


@dataclasses.dataclass
class _Constraints:
    """Constraint sets of the factory (HPP ``Constraints``: grasps, pregrasps, numerical)."""

    items: list[AnyConstraint] = dataclasses.field(default_factory=list)

    def __add__(self, other: _Constraints) -> _Constraints:
        out = list(self.items)
        out += [c for c in other.items if all(c is not x for x in out)]
        return _Constraints(out)

    def __sub__(self, other: _Constraints) -> _Constraints:
        return _Constraints([c for c in self.items if all(c is not x for x in other.items)])

    def empty(self) -> bool:
        return not self.items


class ConstraintFactory:
    """Grasp / pre-grasp / placement constraints of a problem, built once and shared."""

    def __init__(
        self,
        problem: ManipulationProblem,
        placement_margin: float = 0.0,
        preplacement_distance: float = 0.05,
        object_contacts: Mapping[str, Sequence[str]] | None = None,
        environment_contacts: Sequence[str] | None = None,
    ) -> None:
        self.problem = problem
        self.margin = placement_margin
        self.preplace = preplacement_distance
        self.object_contacts = object_contacts or {
            o: list(i.contacts) for o, i in problem.objects.items()
        }
        self.env_contacts = list(
            environment_contacts
            if environment_contacts is not None
            else problem.environment_contacts
        )
        self._grasp: dict[tuple[str, str], dict[str, _Constraints]] = {}
        self._place: dict[str, dict[str, _Constraints]] = {}

    def grasp(self, gripper: str, handle: str) -> dict[str, _Constraints]:
        """{'grasp', 'complement', 'pregrasp'} for gripper -> handle (HPP Handle::create*)."""
        key = (gripper, handle)
        if key not in self._grasp:
            p = self.problem
            g, h = p.grippers[gripper], p.handles[handle]
            M_JG = p.model.frames[g.frame_id].placement
            M_JH = p.model.frames[h.frame_id].placement
            name = f"{gripper} grasps {handle}"
            mask = np.asarray(h.mask, dtype=bool)
            on_freeflyer = p.model.joints[h.joint_id].nq == 7 and p.model.parents[h.joint_id] == 0
            if mask.all() and on_freeflyer:
                grasp: AnyConstraint = ExplicitRelativePose(
                    name, p.model, h.joint_id, g.joint_id, M_JG, M_JH
                )
                complement = _Constraints()
            else:
                grasp = RelativeTransformation(name, g.joint_id, M_JG, h.joint_id, M_JH, mask)
                complement = (
                    _Constraints()
                    if mask.all()
                    else _Constraints(
                        [
                            RelativeTransformation(
                                f"{name}/complement",
                                g.joint_id,
                                M_JG,
                                h.joint_id,
                                M_JH,
                                ~mask,
                                parametrised=True,
                            )
                        ]
                    )
                )
            shift = (g.clearance + h.clearance) * np.asarray(h.approach, dtype=float)
            # HPP createPreGrasp: the handle seen from the gripper is `shift` ahead along the
            # approach axis, i.e. the gripper waits `clearance` behind the handle.
            pregrasp = RelativeTransformation(
                f"{gripper} pregrasps {handle}",
                g.joint_id,
                M_JG * pin.SE3(np.eye(3), shift),
                h.joint_id,
                M_JH,
                mask,
            )
            self._grasp[key] = {
                "grasp": _Constraints([grasp]),
                "complement": complement,
                "pregrasp": _Constraints([pregrasp]),
            }
        return self._grasp[key]

    def placement(self, obj: str) -> dict[str, _Constraints]:
        """{'placement', 'complement', 'preplacement'} of an object (HPP buildPlacement).

        Without contact surfaces the object's joint is locked instead (complement only).
        """
        if obj not in self._place:
            p = self.problem
            contacts = self.object_contacts.get(obj, [])
            # Surfaces an object can rest on: the environment's and the other objects' (a
            # stack), never its own.
            env = [c for c in self.env_contacts if p.contacts[c].owner != obj]
            if not contacts or not env:
                lock = LockedJoint(f"{obj}/root_joint", p.model, p.objects[obj].joint_id)
                self._place[obj] = {
                    "placement": _Constraints(),
                    "complement": _Constraints([lock]),
                    "preplacement": _Constraints(),
                }
            else:
                place = Placement(f"place_{obj}", p, obj, contacts, env, self.margin)
                comp = PlacementComplement(f"place_{obj}/complement", place)
                pre = Placement(
                    f"preplace_{obj}",
                    p,
                    obj,
                    contacts,
                    env,
                    self.margin + self.preplace,
                )
                self._place[obj] = {
                    "placement": _Constraints([place]),
                    "complement": _Constraints([comp]),
                    "preplacement": _Constraints([pre]),
                }
        return self._place[obj]


@dataclasses.dataclass
class _StateInfo:
    grasps: tuple[int | None, ...]
    state: State
    manifold: _Constraints
    foliation: _Constraints


class GraphFactory:
    """Generate a :class:`ConstraintGraph` (see the module docstring).

    ``grippers``: gripper names; ``objects``: {object: handle names}; ``rules``: pruning.
    ``graph_constraints``: constraints of every state (humanoid balance, feet).
    """

    def __init__(
        self,
        problem: ManipulationProblem,
        grippers: Sequence[str],
        objects: Mapping[str, Sequence[str]],
        rules: Sequence[Rule] = (),
        constraint_factory: ConstraintFactory | None = None,
        graph_constraints: Sequence[AnyConstraint] = (),
        error_threshold: float = 1e-4,
        max_iterations: int = 40,
        line_search: LineSearch = LineSearch(),
        name: str = "graph",
    ) -> None:
        for g in grippers:
            if g not in problem.grippers:
                raise GraphError(f"unknown gripper '{g}' (known: {sorted(problem.grippers)})")
        self.problem = problem
        self.grippers = tuple(grippers)
        self.objects = tuple(objects)
        handles: list[str] = []
        self.object_of_handle: list[int] = []
        for io, o in enumerate(self.objects):
            if o not in problem.objects:
                raise GraphError(f"unknown object '{o}' (known: {sorted(problem.objects)})")
            for h in objects[o]:
                if h not in problem.handles:
                    raise GraphError(f"unknown handle '{h}' (known: {sorted(problem.handles)})")
                handles.append(h)
                self.object_of_handle.append(io)
        self.handles = tuple(handles)
        self.allowed = GraspRules(self.grippers, self.handles, rules)
        self.cf = constraint_factory or ConstraintFactory(problem)
        self.graph = ConstraintGraph(
            problem, name, graph_constraints, error_threshold, max_iterations, line_search
        )
        self._states: dict[tuple[int | None, ...], _StateInfo] = {}
        self._transitions: set[str] = set()
        self.level_sets = True  # level-set twins of the transitions (graph.LevelSetEdge)

    # ------------------------------------------------------------------------------ names
    def state_name(self, grasps: tuple[int | None, ...], abbrev: bool = False) -> str:
        parts = [
            (str(ig) if abbrev else self.grippers[ig])
            + ("-" if abbrev else " grasps ")
            + (str(ih) if abbrev else self.handles[ih])
            for ig, ih in enumerate(grasps)
            if ih is not None
        ]
        if not parts:
            return "f" if abbrev else "free"
        return (":" if abbrev else " : ").join(parts)

    # ------------------------------------------------------------------------------ algorithm
    def generate(self) -> ConstraintGraph:
        """Run the recursion; returns the graph."""
        self._recurse(self.grippers, self.handles, (None,) * len(self.grippers), 0)
        return self.graph

    def _recurse(self, grippers, handles, grasps, depth) -> None:
        allowed = self.allowed(grasps)
        current = self._make_state(grasps, depth) if allowed else None
        if not grippers or not handles:
            return
        for ig, g in enumerate(grippers):
            ngrippers = grippers[:ig] + grippers[ig + 1 :]
            isg = self.grippers.index(g)
            for ih, h in enumerate(handles):
                nhandles = handles[:ih] + handles[ih + 1 :]
                ish = self.handles.index(h)
                ngrasps = grasps[:isg] + (ish,) + grasps[isg + 1 :]
                next_allowed = self.allowed(ngrasps)
                is_new = ngrasps not in self._states
                nxt = self._make_state(ngrasps, depth + 1) if next_allowed else None
                if current is not None and nxt is not None:
                    self._make_transition(current, nxt, isg)
                if is_new:
                    self._recurse(ngrippers, nhandles, ngrasps, depth + 2)

    def _grasped(self, grasps, io: int) -> bool:
        return any(ih is not None and self.object_of_handle[ih] == io for ih in grasps)

    def _make_state(self, grasps, priority) -> _StateInfo:
        if grasps in self._states:
            return self._states[grasps]
        manifold, foliation = _Constraints(), _Constraints()
        for ig, ih in enumerate(grasps):
            if ih is not None:
                gc = self.cf.grasp(self.grippers[ig], self.handles[ih])
                manifold += gc["grasp"]
                foliation += gc["complement"]
        for io, o in enumerate(self.objects):
            if not self._grasped(grasps, io):
                pc = self.cf.placement(o)
                manifold += pc["placement"]
                foliation += pc["complement"]
        name = self.state_name(grasps)
        state = self.graph.add_state(
            name,
            manifold.items,
            waypoint=False,
            priority=priority,
            grasps={
                self.grippers[ig]: self.handles[ih]
                for ig, ih in enumerate(grasps)
                if ih is not None
            },
        )
        info = _StateInfo(grasps, state, manifold, foliation)
        self._states[grasps] = info
        # Loop transition: move keeping the grasps and the placements (weight 0, as HPP: used
        # to connect nodes, never sampled for extension).
        loop = Edge(
            self.graph,
            f"Loop | {self.state_name(grasps, True)}",
            state,
            state,
            state,
            foliation.items,
            weight=0.0,
        )
        loop.reverse_edge = loop
        self.graph.add_edge(loop)
        return info

    def _make_transition(self, sf: _StateInfo, st: _StateInfo, ig: int) -> None:
        ih = st.grasps[ig]
        assert ih is not None  # st is sf with gripper ig grasping (see _recurse)
        g, h = self.grippers[ig], self.handles[ih]
        fwd = f"{g} > {h} | {self.state_name(sf.grasps, True)}"
        bwd = f"{g} < {h} | {self.state_name(st.grasps, True)}"
        if fwd in self._transitions:
            return
        self._transitions.add(fwd)
        io = self.object_of_handle[ih]
        no_place = self._grasped(sf.grasps, io)
        gc = self.cf.grasp(g, h)
        if no_place:
            pc = ppc = _Constraints()
        else:
            pl = self.cf.placement(self.objects[io])
            pc, ppc = pl["placement"], pl["preplacement"]
        manifold = _Constraints(sf.state.constraints) - pc
        pregrasp = not gc["pregrasp"].empty()
        intersec = not gc["grasp"].empty() and not pc.empty()
        preplace = not ppc.empty()
        graph = self.graph
        wstates = [sf.state]
        held = st.state.grasps  # the waypoints after the pre-grasp already hold the handle
        if pregrasp:
            wstates.append(
                graph.add_state(
                    fwd + "_pregrasp",
                    (pc + gc["pregrasp"] + manifold).items,
                    waypoint=True,
                    grasps=sf.state.grasps,
                )
            )
        if intersec:
            wstates.append(
                graph.add_state(
                    fwd + "_intersec",
                    (pc + gc["grasp"] + manifold).items,
                    waypoint=True,
                    grasps=held,
                )
            )
        if preplace:
            wstates.append(
                graph.add_state(
                    fwd + "_preplace",
                    (ppc + gc["grasp"] + manifold).items,
                    waypoint=True,
                    grasps=held,
                )
            )
        wstates.append(st.state)
        n = len(wstates) - 1
        # Sub-edges before the grasp exists lie in the source state (object still placed);
        # the others in the destination state (object held) -- HPP's M = 1 + pregrasp.
        m = 0 if gc["grasp"].empty() else 1 + int(pregrasp)
        fsub, bsub = [], []
        for i in range(n):
            containing, fol = (sf.state, sf.foliation) if i < m else (st.state, st.foliation)
            extra = _Constraints()
            if pregrasp and i == 1:
                extra = gc["complement"]
            ef = Edge(
                graph,
                f"{fwd}_{i}{i + 1}",
                wstates[i],
                wstates[i + 1],
                containing,
                (fol + extra).items,
                weight=-1,
                short=i > 0,
            )
            eb = Edge(
                graph,
                f"{bwd}_{i + 1}{i}",
                wstates[i + 1],
                wstates[i],
                containing,
                (fol + extra).items,
                weight=-1,
                short=i < n - 1,
            )
            ef.reverse_edge, eb.reverse_edge = eb, ef
            fsub.append(ef)
            bsub.append(eb)
        bsub.reverse()
        if n == 1:
            e1 = Edge(graph, fwd, sf.state, st.state, fsub[0].containing, fsub[0].constraints)
            e2 = Edge(graph, bwd, st.state, sf.state, bsub[0].containing, bsub[0].constraints)
            e1.reverse_edge, e2.reverse_edge = e2, e1
            graph.add_edge(e1)
            graph.add_edge(e2)
            return
        wf = WaypointEdge(graph, fwd, sf.state, st.state, sf.state, fsub)
        wb = WaypointEdge(graph, bwd, st.state, sf.state, sf.state, bsub)
        wf.reverse_edge, wb.reverse_edge = wb, wf
        for e in fsub + bsub:
            graph.add_edge(e)
        graph.add_edge(wf)
        graph.add_edge(wb)
        # Level-set twins: the leaf a transition lands on, where the transition does not fix
        # it, can be copied from another component (graph.LevelSetEdge) -- a grasp's free
        # parameters (complement of a partial grasp), a release's placement.  HPP creates them
        # only when both states have leaves (crossedFoliation); a single object needs them as
        # well: the goal's component then puts the object back exactly where the start's has it.
        if self.level_sets:
            grasp_leaf = st.foliation - sf.foliation
            if not sf.foliation.empty() and not grasp_leaf.empty():
                graph.add_edge(LevelSetEdge(graph, wf, 0, grasp_leaf.items, st.state))
            place_leaf = sf.foliation - st.foliation
            if not no_place and not place_leaf.empty():
                graph.add_edge(LevelSetEdge(graph, wb, 0, place_leaf.items, sf.state))


def graph_constraints_from_settings(
    problem: ManipulationProblem, entries: Sequence[dict[str, Any]]
) -> list[AnyConstraint]:
    """Constraints of every state, from the problem file (values taken at ``init``):

    ``{fixed_frame: <frame>, mask: [6 x 0/1]}``: the frame keeps its initial pose (a foot on
    the ground); ``{com: [1, 1, 0]}``: the centre of mass keeps its initial position on the
    masked axes (quasi-static balance over fixed feet, thesis §3.2.1 g_CoM);
    ``{locked_joint: <joint>}``: the joint keeps its initial value.
    """
    from marionette.planning.constraints import ComPosition, Kinematics, Transformation

    if not entries:
        return []
    if problem.q_init is None:
        raise GraphError("graph constraints take their values from 'init', which is missing")
    kin = Kinematics(problem.model)
    kin.update(problem.q_init, jacobians=False)
    out: list[AnyConstraint] = []
    for e in entries:
        if "fixed_frame" in e:
            fid = problem.frame_id(e["fixed_frame"])
            f = problem.model.frames[fid]
            X = kin.data.oMi[f.parentJoint] * f.placement
            out.append(
                Transformation(
                    f"{e['fixed_frame']} fixed",
                    f.parentJoint,
                    f.placement,
                    X,
                    [bool(v) for v in e.get("mask", [1] * 6)],
                )
            )
        elif "com" in e:
            mask = [bool(v) for v in e["com"]]
            c = ComPosition("com", 0, pin.SE3.Identity(), mask=mask)
            c.rhs = c.value(kin).copy()
            out.append(c)
        elif "locked_joint" in e:
            name = e["locked_joint"]
            if not problem.model.existJointName(name):
                raise GraphError(f"locked_joint: no joint {name}")
            jid = problem.model.getJointId(name)
            lk = LockedJoint(f"{name} locked", problem.model, jid)
            lk.rhs_from_q(problem.q_init)
            lk.parametrised = False
            out.append(lk)
        else:
            raise GraphError(f"unknown graph constraint {e}: use fixed_frame, com or locked_joint")
    return out


def graph_from_settings(
    problem: ManipulationProblem, graph_constraints: Sequence[AnyConstraint] = ()
) -> ConstraintGraph:
    """Build the graph described by the problem file's ``graph:`` section."""
    s: dict[str, Any] = problem.settings
    graph_constraints = list(graph_constraints) + graph_constraints_from_settings(
        problem, s.get("constraints", []) or []
    )
    grippers = s.get("grippers", list(problem.grippers))
    objs = s.get("objects") or {
        o: {"handles": list(i.handles), "contacts": list(i.contacts)}
        for o, i in problem.objects.items()
    }
    objects = {o: list(v.get("handles", problem.objects[o].handles)) for o, v in objs.items()}
    contacts = {o: list(v.get("contacts", problem.objects[o].contacts)) for o, v in objs.items()}
    cf = ConstraintFactory(
        problem,
        float(s.get("placement_margin", 0.0)),
        float(s.get("preplacement_distance", 0.05)),
        contacts,
        s.get("environment_contacts"),
    )
    rules = [
        Rule(list(r["grippers"]), list(r["handles"]), bool(r.get("link", False)))
        for r in s.get("rules", []) or []
    ]
    ls = s.get("line_search", {}) or {}
    factory = GraphFactory(
        problem,
        grippers,
        objects,
        rules,
        cf,
        graph_constraints,
        float(s.get("error_threshold", 1e-4)),
        int(s.get("max_iterations", 40)),
        LineSearch(**ls) if ls else LineSearch(),
        name=problem.name,
    )
    graph = factory.generate()
    graph.path_step = float(s.get("path_step", graph.path_step))
    # HPP's setWeight: how often Manipulation-RRT samples a transition (0: only to connect).
    for name, w in (s.get("weights", {}) or {}).items():
        if name not in graph.edges or graph.edges[name].parent is not None:
            raise GraphError(f"weights: no top-level transition {name!r}")
        if float(w) < 0:
            raise GraphError(f"weights: {name!r} must be >= 0, got {w}")
        graph.edges[name].weight = float(w)
    return graph
