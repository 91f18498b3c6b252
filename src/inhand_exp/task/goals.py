"""Goal datasets (paper section IV-B): (X0, Xg) pairs in three groups, deterministic from a seed.

X0 is a pose of the workspace with a random grasp that holds it. Then:

- easy: Xg is reachable by reposing alone from the initial contacts (every pose on the straight
  path from X0 to Xg is held by those contacts, links clear);
- medium: Xg is held by some grasp of the initial posture (which side each finger is on), with
  other contact coordinates, so sliding may be needed;
- hard: Xg is a pose of the workspace held by a grasp of another posture than X0's
  (``hard_goal_posture="other"``, the default, as the authors' own code drew its hard goals);
  with ``any``, any pose some grasp holds. A pole's hard test set draws a share of its pairs
  (``flip_share``, ``goals.hard_flip_share``: every 4th at 0.25) from the pairs that need a
  flip, since arbitrary ones need one too rarely (13 % of the reachable "other" pairs).

X0 and Xg are drawn uniformly from the part of the workspace the hand holds
(``sample.random_grasp``), so poses only one posture holds (large tilts) are as likely as the
upright ones every posture holds. With ``goals.x0`` every pair starts from that pose instead,
held by one grasp drawn once from the seed (``fixed_start``; the paper's cube study).

Every pair carries ``needs_flip``: no grasp of the initial posture holds the object at Xg, nor
anywhere within the success tolerance round it, by the controllers' own model
(``sample.grasp_of``: reach, joint limits, links and palm clear, a squeeze strictly inside the
friction cones).

Every medium and hard pair of a pole also carries ``lone_down``: the initial posture holds the
object at the goal, but only with its lone finger (the one alone on its face) lower on the pole
than it starts. Sliding it there is what friction forbids while the pole is within about 1 rad
of upright (``lone_descends``), so such a pair needs a large tilt or a flip on the way.

A hard pair is kept only when the action set can reach its goal (``goals.reachable_only``):
some posture that flips lead to from X0's holds the object at Xg (``flips_to``). The paper's
action set flips the left and right fingers only (Table I), so the middle finger never changes
side, and the six postures of a pole form two families of three that no flip joins. Of the
"other" hard pairs of the default workspace, 17 % have a goal that only the other family
holds: no policy can solve them. Pair ``i`` of a split is drawn from its own
generator seeded by (seed, group, split, i), so a set does not depend on how many pairs are
drawn or in what order, and the test set (split "test") never overlaps the training
distribution (split "train") by construction of the streams.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pandas as pd

from inhand_exp.config import PrimitivesConfig
from inhand_exp.control.grasp import Contacts, Face, Posture
from inhand_exp.control.hand import GeometryError, HandModel
from inhand_exp.control.repose import strict_hold
from inhand_exp.control.sample import (
    Workspace,
    elongated,
    grasp_of,
    holds_at,
    lone_finger,
    postures,
    random_grasp,
)
from inhand_exp.errors import GoalsError

GROUPS = ("easy", "medium", "hard")
# training only: flip, a hard pair that needs a flip; lone, a medium pair whose lone finger must
# end lower on the pole (``lone_down``)
TRAIN_GROUPS = (*GROUPS, "flip", "lone")
SPLITS = ("train", "test")
COLUMNS = ("group", "x0_x", "x0_z", "x0_theta", "xg_x", "xg_z", "xg_theta",
           "faces", "c0", "c1", "c2")
OPTIONAL = ("needs_flip", "lone_down")  # computed when a file lacks them
EASY_STEP = np.array([0.06, 0.06, 0.6])  # largest easy offset (m, m, rad)
HARD_POSTURES = ("other", "any")
FLIP_FINGERS = (0, 2)  # the action table's flip left and flip right
LONE_SLACK_M = 0.005  # the grid of ``face_coords``: a lone finger "as high" within one step


@dataclass(frozen=True)
class GoalPair:
    """An initial pose and grasp, and a goal pose (m, m, rad); ``needs_flip``: no grasp of the
    initial posture holds the object at the goal; ``lone_down``: only grasps with the lone
    finger lower on the pole do (``lone_descends``)."""

    group: str
    x0: np.ndarray
    xg: np.ndarray
    contacts: Contacts
    needs_flip: bool = False
    lone_down: bool = False


def reachable(model: HandModel, contacts: Contacts, pose: np.ndarray) -> bool:
    """The grasp ``contacts`` can hold the object at ``pose`` (IK within limits, links clear)."""
    return holds_at(model, contacts, pose) is not None


def holds_near(model: HandModel, posture: Posture, xg: np.ndarray,
               tol: tuple[float, float] = (0.01, 0.1), lone_min: float | None = None) -> bool:
    """Some grasp of ``posture`` holds the object where it would count as at the goal: at
    ``xg`` or at a pose of a 3 x 3 x 3 grid spanning 90 % of the success tolerance ``tol``
    (m, rad) round it (a deterministic search, the goal itself first); with ``lone_min``, a
    grasp whose lone finger is at that coordinate or above."""
    steps = [0.0, -0.9, 0.9]
    grid = sorted(itertools.product(steps, steps, steps), key=lambda d: sum(map(abs, d)))
    scale = np.array([tol[0], tol[0], tol[1]])
    return any(grasp_of(model, posture, xg + np.array(d) * scale, lone_min=lone_min)
               is not None for d in grid)


def lone_descends(model: HandModel, contacts: Contacts, xg: np.ndarray,
                  tol: tuple[float, float] = (0.01, 0.1)) -> bool:
    """Every grasp of the initial posture that holds a pole near ``xg`` (``holds_near``) has
    its lone finger lower on the pole than in ``contacts`` (by more than ``LONE_SLACK_M``).

    Sliding the lone finger towards the pole's lower end is what friction forbids on an
    upright pole: its normal force alone balances the other two fingers' normal forces, so
    their friction can bear at most mu times its normal force, while they must carry the
    pole's weight plus the sliding finger's drag, which is exactly that much. Tilted by more
    than about 1 rad, the normal forces bear part of the weight and the slide can become
    possible (``Slide.start`` decides). False for other shapes, and when the posture does not
    hold the goal at all (``needs_flip``)."""
    if not elongated(model):
        return False
    lo = contacts.coords[lone_finger(contacts.posture)] - LONE_SLACK_M
    return not holds_near(model, contacts.posture, xg, tol, lone_min=lo) and holds_near(
        model, contacts.posture, xg, tol)


def needs_flip(model: HandModel, posture: Posture, xg: np.ndarray,
               tol: tuple[float, float] = (0.01, 0.1)) -> bool:
    """No grasp of ``posture`` holds the object anywhere it would count as at the goal."""
    return not holds_near(model, posture, xg, tol)


def flip_fingers(model: HandModel, prim) -> tuple[int, ...] | None:
    """The fingers whose flips change a pole's posture in the action set of ``prim``: flip left
    and flip right (fingers 0 and 2, paper Table I), or none without flips. None for other
    shapes, whose release and land put a finger on another face (``task.reach`` searches
    what they reach, as a diagnostic)."""
    if not elongated(model):
        return None
    return FLIP_FINGERS if prim.flip else ()


def reach_fingers(model: HandModel, cfg) -> tuple[int, ...] | None:
    """The ``fingers`` argument of ``goal_set`` for a run's config: the action set's flip
    fingers with ``goals.reachable_only``, else None (no pair is left out)."""
    return flip_fingers(model, cfg["primitives"]) if cfg["goals"]["reachable_only"] else None


def flip_distances(posture: Posture, fingers: tuple[int, ...]) -> dict[Posture, int]:
    """The postures a sequence of flips of ``fingers`` leads to from ``posture``, with the
    fewest flips each takes. A flip moves a finger to the opposite long face and needs the two
    staying fingers on opposite faces (they hold the pole alone meanwhile). With fingers 0 and
    2 only, the middle finger never changes side: the six postures form two families of three,
    and no flip joins them."""
    dist, frontier = {posture: 0}, [posture]
    while frontier:
        nxt = []
        for p in frontier:
            for k in fingers:
                a, b = (j for j in range(3) if j != k)
                if p.faces[a] == p.faces[b]:
                    continue
                faces = list(p.faces)
                faces[k] = Face.RIGHT if faces[k] == Face.LEFT else Face.LEFT
                q = Posture(tuple(faces))
                if q not in dist:
                    dist[q] = dist[p] + 1
                    nxt.append(q)
        frontier = nxt
    return dist


def flips_to(model: HandModel, posture: Posture, xg: np.ndarray, fingers: tuple[int, ...],
             tol: tuple[float, float] = (0.01, 0.1)) -> int | None:
    """The fewest flips of ``fingers`` after which some grasp holds the object at the goal
    (``holds_near``), or None when no posture they lead to holds it."""
    for p, n in sorted(flip_distances(posture, fingers).items(), key=lambda t: t[1]):
        if holds_near(model, p, xg, tol):
            return n
    return None


def _apart(x0: np.ndarray, xg: np.ndarray, tol: tuple[float, float]) -> bool:
    """Not already solved: outside the success tolerance."""
    return bool(max(abs(xg[0] - x0[0]), abs(xg[1] - x0[1])) >= tol[0]
                or abs(xg[2] - x0[2]) >= tol[1])


def _inside(ws: Workspace, pose: np.ndarray) -> bool:
    return bool(np.all(pose >= np.array(ws.low)) and np.all(pose <= np.array(ws.high)))


Start = tuple[np.ndarray, Contacts]
PRESS_M = 0.0005  # initial fingertip press into the surface (m)
EDGE_M = 0.001  # a contact closer than this to its face's end touches the edge, not the face


def settable(true_model: HandModel):
    """A test of pairs: the fingers can be put on the *simulated* object at X0 with the pair's
    grasp (``true_model``: the hand and the perturbed object; pairs are drawn on the nominal
    one, and a thicker, thinner or longer pole may not fit the same contacts). Every contact
    must lie on its face of the simulated object, ``EDGE_M`` or more inside its end: the
    nominal sampler keeps tips two radii from the nominal ends, which is where a pole a
    tenth shorter ends, and a tip put there rests on the edge and slips off it."""

    def fits(pair: GoalPair) -> bool:
        c = pair.contacts
        if any(on and abs(coord) > true_model.shape.half_extent(face) - EDGE_M
               for coord, face, on in zip(c.coords, c.posture.faces, c.active, strict=True)):
            return False
        try:
            true_model.grasp_q(pair.contacts, pair.x0, PRESS_M)
        except GeometryError:
            return False
        return True

    return fits


def fixed_start(model: HandModel, pose, seed: int) -> Start:
    """``pose`` and one grasp that holds it, drawn once from ``seed`` (a random posture among
    those that hold it, then random contacts): the start of every pair when ``goals.x0`` is
    set, as in the paper's cube study."""
    pose = np.asarray(pose, dtype=float)
    rng = np.random.default_rng([seed, 7])
    choices = postures(model)
    for k in rng.permutation(len(choices)):
        contacts = grasp_of(model, choices[int(k)], pose, rng, tries=60)
        if contacts is not None and holds_at(model, contacts, pose, press=0.0005,
                                             margin=0.1) is not None:
            return pose, contacts
    raise GoalsError(f"goals.x0={pose.round(4).tolist()}: no grasp of the hand holds the "
                     f"object there (reach, joint limits, links and palm clear, a squeeze)")


def start_of(model: HandModel, goals) -> Start | None:
    """The fixed start of the ``goals`` config node (``x0``), or None: each pair draws one."""
    x0 = goals.get("x0")
    return None if x0 is None else fixed_start(model, list(x0), int(goals["seed"]))


def sample_pair(model: HandModel, group: str, rng: np.random.Generator,
                workspace: Workspace | None = None, hard_posture: str = "other",
                tol: tuple[float, float] = (0.01, 0.1), max_tries: int = 500,
                start: Start | None = None, fits=None,
                fingers: tuple[int, ...] | None = FLIP_FINGERS) -> GoalPair:
    """One pair of ``group`` (or, for ``flip``, a hard pair that needs a flip, and for
    ``lone``, a medium pair whose lone finger must end lower on the pole: training groups that
    give those rare pairs a share of their own), by rejection sampling;
    from ``start`` (a pose and its grasp) when given, else from a random grasp of the
    workspace; only pairs that ``fits`` accepts (e.g. ``settable``), when given. With
    ``fingers`` (``flip_fingers``) and a pole, a hard pair is kept only when flips of those
    fingers lead to a posture that holds the object at the goal: no sequence of the action set
    reaches the others."""
    if group not in TRAIN_GROUPS:
        raise ValueError(f"goal group must be one of {TRAIN_GROUPS}, got {group!r}")
    if hard_posture not in HARD_POSTURES:
        raise ValueError(f"hard_posture must be one of {HARD_POSTURES}, got {hard_posture!r}")
    ws = workspace or Workspace()
    for _ in range(max_tries):
        x0, c0 = start if start is not None else random_grasp(model, rng, ws)[:2]
        if group == "easy":
            xg = x0 + rng.uniform(-EASY_STEP, EASY_STEP)
            path = [x0 + (xg - x0) * s for s in np.linspace(0.2, 1.0, 5)]
            ok = _inside(ws, xg) and all(reachable(model, c0, p) for p in path)
        elif group in ("medium", "lone"):
            xg = ws.draw(rng)
            ok = grasp_of(model, c0.posture, xg, rng, tries=8) is not None
        else:
            exclude = c0.posture if hard_posture == "other" else None
            xg, _, _ = random_grasp(model, rng, ws, exclude=exclude)
            ok = True
        if ok and _apart(x0, xg, tol):
            flip = False
            if group in ("hard", "flip"):
                if fingers is not None and elongated(model):
                    n = flips_to(model, c0.posture, xg, fingers, tol)
                    if n is None:  # no sequence of the action set reaches the goal
                        continue
                    flip = n > 0
                else:
                    flip = needs_flip(model, c0.posture, xg, tol)
            if group == "flip" and not flip:
                continue
            if group == "lone" and not lone_descends(model, c0, xg, tol):
                continue
            named = {"flip": "hard", "lone": "medium"}.get(group, group)
            pair = GoalPair(named, x0, xg, c0, flip, lone_down=group == "lone")
            if fits is None or fits(pair):
                return pair
    raise GeometryError(f"no {group} goal pair found in {max_tries} tries")


def flip_slot(i: int, share: float) -> bool:
    """Pair ``i`` of a hard set with a flip share ``share`` is drawn from the pairs that need a
    flip: ``floor((i + 1) * share) > floor(i * share)``, so the first ``k`` pairs hold
    ``floor(k * share)`` such slots (pairs 3, 7, 11, ... at 0.25)."""
    return math.floor((i + 1) * share) > math.floor(i * share)


def goal_set(model: HandModel, group: str, n: int, seed: int, split: str = "test",
             workspace: Workspace | None = None, hard_posture: str = "other",
             start: Start | None = None, fits=None,
             fingers: tuple[int, ...] | None = FLIP_FINGERS,
             flip_share: float = 0.0) -> list[GoalPair]:
    """``n`` pairs of ``group``; pair ``i`` depends only on (seed, group, split, i), ``start``
    and, where they reject the first draw, ``fits`` and ``fingers`` (see ``sample_pair``).

    With ``flip_share`` (a pole's hard set), the pairs of ``flip_slot`` are drawn, from the
    same generator, as pairs that need a flip (the ``flip`` group); the others are the pairs
    the set holds without it."""
    if group not in GROUPS:
        raise ValueError(f"goal group must be one of {GROUPS}, got {group!r}")
    if split not in SPLITS:
        raise ValueError(f"split must be one of {SPLITS}, got {split!r}")
    if not 0.0 <= flip_share <= 1.0:
        raise ValueError(f"flip_share must be within [0, 1], got {flip_share}")
    g, s = GROUPS.index(group), SPLITS.index(split)
    share = flip_share if group == "hard" and elongated(model) else 0.0
    pairs = [sample_pair(model, "flip" if flip_slot(i, share) else group,
                         np.random.default_rng([seed, g, s, i]), workspace, hard_posture,
                         start=start, fits=fits, fingers=fingers)
             for i in range(n)]
    return [with_lone_down(model, p) for p in pairs]


def with_lone_down(model: HandModel, pair: GoalPair) -> GoalPair:
    """``pair`` with its ``lone_down`` flag (``lone_descends``; easy pairs never: their goal
    is reached by reposing alone)."""
    down = pair.group != "easy" and not pair.needs_flip and lone_descends(
        model, pair.contacts, pair.xg)
    return replace(pair, lone_down=down)


def to_frame(pairs: list[GoalPair]) -> pd.DataFrame:
    rows = [(p.group, *p.x0, *p.xg, str(p.contacts.posture), *p.contacts.coords, p.needs_flip,
             p.lone_down) for p in pairs]
    return pd.DataFrame(rows, columns=[*COLUMNS, *OPTIONAL])


def save_goals(pairs: list[GoalPair], path: str | Path) -> Path:
    """Write the pairs as CSV (one row per episode); refuses to overwrite."""
    path = Path(path)
    if path.exists():
        raise FileExistsError(f"{path} exists; goal sets are never overwritten")
    to_frame(pairs).to_csv(path, index=False, float_format="%.9g")
    return path


def _flag(v) -> bool | None:
    """A boolean cell as pandas reads it (bool, 0/1 or the words), or None."""
    if isinstance(v, bool | np.bool_):
        return bool(v)
    if isinstance(v, int | float | np.integer | np.floating) and v in (0, 1):
        return bool(v)
    return {"true": True, "false": False}.get(str(v).strip().lower())


def load_goals(path: str | Path, model: HandModel | None = None) -> list[GoalPair]:
    """Read a goal set, CSV (as ``save_goals`` writes) or Parquet with the same columns; errors
    name the row and column. ``needs_flip`` and ``lone_down`` are optional; where a file lacks
    them, they are computed with ``model`` (False without one)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"goal file {path} not found")
    suffix = path.suffix.lower()
    if suffix not in (".csv", ".parquet"):
        raise GoalsError(f"{path}: goal files are CSV or Parquet (got {path.suffix!r})")
    try:
        df = pd.read_csv(path) if suffix == ".csv" else pd.read_parquet(path)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as err:
        raise GoalsError(f"{path}: not a readable CSV ({err})") from None
    except (OSError, ValueError) as err:  # pyarrow's errors derive from these
        raise GoalsError(f"{path}: not a readable Parquet file ({err})") from None
    missing = [c for c in COLUMNS if c not in df.columns]
    if missing:
        raise GoalsError(f"{path}: missing column(s) {', '.join(missing)}")
    if df.empty:
        raise GoalsError(f"{path}: no goal rows (a header alone)")
    pairs = []
    faces_by_name = {f.name.lower(): f for f in Face}
    first = 2 if suffix == ".csv" else 1  # a CSV's line 1 is the header
    where = "line" if suffix == ".csv" else "row"
    for row, r in enumerate(df.itertuples(index=False), start=first):
        try:
            values = [float(getattr(r, c)) for c in COLUMNS if c not in ("group", "faces")]
        except (TypeError, ValueError) as err:
            raise GoalsError(f"{path} {where} {row}: a pose or contact is not a number ({err})") \
                from None
        if not all(np.isfinite(values)):
            raise GoalsError(f"{path} {where} {row}: non-finite pose or contact value")
        if r.group not in GROUPS:
            raise GoalsError(f"{path} {where} {row}: group must be one of {GROUPS}, "
                             f"got {r.group!r}")
        names = str(r.faces).split("/")
        if len(names) != 3 or any(n not in faces_by_name for n in names):
            raise GoalsError(f"{path} {where} {row}: faces must be three of "
                             f"{sorted(faces_by_name)} joined by '/', got {r.faces!r}")
        posture = Posture(tuple(faces_by_name[n] for n in names))
        xg = np.array(values[3:6])
        flags = {}
        for name in OPTIONAL:
            if name in df.columns:
                flags[name] = _flag(getattr(r, name))
                if flags[name] is None:
                    raise GoalsError(f"{path} {where} {row}: {name} must be true or false, "
                                     f"got {getattr(r, name)!r}")
        if "needs_flip" not in flags:
            flags["needs_flip"] = model is not None and needs_flip(model, posture, xg)
        pair = GoalPair(r.group, np.array(values[0:3]), xg,
                        Contacts(posture, tuple(values[6:9])), flags["needs_flip"])
        if "lone_down" in flags:
            pair = replace(pair, lone_down=flags["lone_down"])
        elif model is not None:
            pair = with_lone_down(model, pair)
        if model is not None:
            why = unplayable(model, pair)
            if why is not None:
                raise GoalsError(f"{path} {where} {row}: {why}")
        pairs.append(pair)
    return pairs


def unplayable(model: HandModel, pair: GoalPair) -> str | None:
    """Why the hand cannot play ``pair``, by the controllers' model, or None: its grasp does not
    hold the object at X0 (reach, joint limits, links and palm clear, a squeeze inside the
    friction cones), or no grasp of any posture holds it at Xg."""
    x0 = np.round(pair.x0, 4).tolist()
    try:
        model.grasp_q(pair.contacts, pair.x0)
    except GeometryError as err:
        return f"the grasp cannot hold the object at X0 = {x0}: {err}"
    if holds_at(model, pair.contacts, pair.x0) is None:
        return f"the grasp cannot hold the object at X0 = {x0}: a joint is at its limit"
    if not strict_hold(model, pair.contacts, PrimitivesConfig()):
        return f"the grasp at X0 = {x0} cannot squeeze the object inside the friction cones"
    if holds_at(model, pair.contacts, pair.xg) is not None:
        return None
    tried = {pair.contacts.posture} if pair.needs_flip else set()
    if any(grasp_of(model, p, pair.xg) is not None for p in postures(model) if p not in tried):
        return None
    return f"no grasp holds the object at Xg = {np.round(pair.xg, 4).tolist()}"
