"""Driving: a fast ego passes a slow, reactive opponent on a SUMO three-lane road.

SUMO simulates a straight three-lane road (lanes 3.2 m wide, 0 = right .. 2 = left) with the
sublane model, so lateral positions are continuous. Both cars start in the centre lane: the ego
at 50 m driving 20 m/s, the opponent 60 m ahead at 10 m/s; a stopped hazard blocks the centre
lane at 230-235 m, so both must leave it. Forward speeds are fixed (speed mode 0: SUMO's car
following never brakes for anyone). One decision step is 1 s (10 SUMO steps of 0.1 s); H = 10
(6 to 30: the ego reaches the opponent in step 6, and the road ends after 30).

- Action: lateral velocity in [-1, 1], times 2 m/s (positive = left), applied every SUMO step
  with ``vehicle.changeSublane``; the ego is kept on the road (|offset| <= 3.9 m).
- Observation: ego and opponent positions, never the opponent's intent:
  ``[ego_x, ego_y, opp_x, opp_y, t/H]``, x in units of 100 m from the ego's start, y in lane
  widths from the centre of the centre lane (left positive).
- Task reward: -1 at the decision step in which the ego's first collision of the interaction
  happens (with the opponent or the hazard), else 0; so an interaction scores -1 or 0.
  Collisions are SUMO's own (``--collision.action warn`` keeps the simulation going,
  ``--collision.mingap-factor 0``: only physical overlap counts).

The opponent (strategy z = the lane it intends to merge into, right or left) drives straight
until the ego's front is within 8 m of its own front, then cuts into lane z at 3 m/s. That is
0.3 s before the cars overlap lengthwise: too late for the ego to react, so it has to commit
to a side before it sees anything; an ego in lane z, or in the centre lane less than about 0.9 m
off its middle away from lane z, is hit (leaning 0.9 m away gets by it, not yet by the hazard).
Strategy dynamics (the paper's): if the ego's centre is in the left lane when its front crosses
the red line (40 m past its start, 2 decision steps in: early enough for the opponent to take
note) the opponent merges right in the next interaction ("faster vehicles pass on the left").
Otherwise it merges into the lane the ego passed it in (the ego's lane when its front passes the
opponent's front; from the centre lane, the side the ego leans to, left on a tie), cutting it
off. Oracle observes z as a one-hot over (right, left).

Resets between interactions restore a saved SUMO state (``simulation.loadState``) and re-apply
the per-vehicle TraCI settings that loading clears (speed modes, lane-change modes, speeds);
SUMO itself is started once per environment, at its first ``reset()`` (constructing one is
cheap, e.g. the throw-away copy gymnasium's ``AsyncVectorEnv`` builds to read the spaces).
libsumo allows one simulation per process: the first reset of a second Driving environment
while another one in the process is running raises ``SimulationSlotError`` (a ``ConfigError``
and a ``RuntimeError``); ``close()`` stops SUMO and releases the process's simulation so a later
environment can start. Use subprocesses (gymnasium ``AsyncVectorEnv``) for parallel
environments; ``backend="traci"`` runs SUMO as a socket server instead (no limit; ~15x slower on
a Zen 4, ``benchmarks/RESULTS.md``).
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
from gymnasium import spaces

from sili_robots.errors import ConfigError, check_choice, check_count
from sili_robots.tasks import sumo_scenario as sc
from sili_robots.tasks.base import RepeatedInteractionEnv
from sili_robots.tasks.sumo_session import BACKENDS, SumoSession

DECISION_SUBSTEPS = 10  # SUMO steps per decision step (1 s)
DECISION_DT = DECISION_SUBSTEPS * sc.STEP_LENGTH
EGO_LATERAL_SPEED = 2.0  # m/s at action 1
MAX_LATERAL_OFFSET = sc.LANE_WIDTH + (sc.LANE_WIDTH - sc.VEHICLE_WIDTH) / 2  # stay on the road
RED_LINE = 40.0  # metres past the ego's start: crossed at the end of decision step 2
REACTION_GAP = 8.0  # the opponent cuts in when the ego's front is this close behind its front
POSITION_SCALE = 100.0  # observation x unit (m)
MAX_HORIZON = 30  # the road is long enough for 30 decision steps
#: the ego reaches the opponent in decision step 6 (a 60 m gap closing at 10 m/s): in a shorter
#: interaction it never meets it, so every policy scores 0 and nothing is learned
MIN_HORIZON = 6
RIGHT, CENTRE, LEFT = 0, sc.CENTRE_LANE, 2
TARGET_LANES = (RIGHT, LEFT)  # the opponent's possible strategies
#: what a closed environment says when it is used again
CLOSED = "this Driving environment was closed; make a new one"


def lane_of(offset: float) -> int:
    """SUMO lane index of a lateral offset (m) from the centre-lane centre."""
    if offset > sc.LANE_WIDTH / 2:
        return LEFT
    if offset < -sc.LANE_WIDTH / 2:
        return RIGHT
    return CENTRE


class DrivingEnv(RepeatedInteractionEnv):
    """Pass a reactive opponent without a collision; it cuts into the lane you passed in."""

    strategy_dim: ClassVar[int] = 2  # one-hot of the opponent's intended lane (right, left)
    #: all the game carries between interactions (SUMO restarts from the same saved state)
    game_state_fields: ClassVar[tuple[str, ...]] = ("target_lane",)
    #: the flags ``_reset_interaction_flags`` clears before SUMO is asked to start the next
    #: interaction: T^z reads the finished one's, so a failed start must give them back
    RESET_CHANGES: ClassVar[tuple[str, ...]] = (
        *RepeatedInteractionEnv.RESET_CHANGES,
        "left_before_red_line",
        "red_line_crossed",
        "passed",
        "passing_offset",
        "opponent_reacted",
        "collided",
        "collision_partners",
        "substeps",
    )
    same_dynamics_arguments: ClassVar[frozenset[str]] = frozenset({"backend"})  # one SUMO

    def __init__(
        self,
        horizon: int = 10,
        backend: str = "libsumo",
    ) -> None:
        try:  # the base class checks against every task's longest, not this road's
            check_count("horizon", horizon, MIN_HORIZON, MAX_HORIZON)
        except ConfigError:
            raise ConfigError(
                f"horizon must be an integer from {MIN_HORIZON} (the step in which the ego "
                f"reaches the opponent) to {MAX_HORIZON} (the road ends) for Driving, got "
                f"{horizon!r}"
            ) from None
        self.target_lane = LEFT
        self.ego_x = self.ego_y = self.opp_x = self.opp_y = 0.0  # metres, see _read_positions
        self._reset_interaction_flags()
        check_choice("SUMO backend", backend, BACKENDS)
        super().__init__(horizon=horizon)
        self.backend = backend
        sc.sumo_binary("sumo")  # fail early if the wheel is broken; SUMO itself starts lazily
        self.session: SumoSession | None = None
        self._closed = False
        self._centre_y = 0.0
        self._state_file = ""

    def _start_simulation(self) -> SumoSession:
        """Start SUMO (first reset only), step once to insert the cars, save that state."""
        if self._closed:
            raise RuntimeError(CLOSED)
        session = SumoSession(sc.scenario_files(), self.backend)
        api = session.api
        with session.guard("preparing the scenario"):
            api.simulationStep()  # inserts the three vehicles at their departure positions
            shape = api.lane.getShape(f"{sc.EDGE_ID}_{sc.CENTRE_LANE}")
            self._centre_y = float(shape[0][1])
            self._state_file = str(session.workdir / "start-state.xml")
            api.simulation.saveState(self._state_file)
        self.session = session
        return session

    # -- spaces
    def _make_action_space(self) -> spaces.Box:
        return spaces.Box(-1.0, 1.0, (1,), np.float32)

    def _base_observation_space(self) -> spaces.Box:
        x_low, x_high = -1.0, (sc.ROAD_LENGTH - sc.EGO_START) / POSITION_SCALE
        y = 1.5
        low = np.array([x_low, -y, x_low, -y, 0.0], np.float32)
        high = np.array([x_high, y, x_high, y, 1.0], np.float32)
        return spaces.Box(low, high)

    # -- strategy
    def strategy_id(self) -> int:
        return self.target_lane

    def strategy_encoding(self) -> np.ndarray:
        return np.array([self.target_lane == RIGHT, self.target_lane == LEFT], np.float32)

    def strategy_choices(self) -> list[int]:
        return list(TARGET_LANES)

    def _set_strategy(self, strategy: int) -> None:
        self.target_lane = int(strategy)

    def _initial_strategy(self) -> None:
        self.target_lane = int(self.np_random.choice(TARGET_LANES))

    def _advance_strategy(self, trajectory: list[dict[str, Any]]) -> None:
        self.target_lane = next_target_lane(self.left_before_red_line, self.passing_offset)

    # -- dynamics
    def _reset_interaction_flags(self) -> None:
        self.left_before_red_line = False
        self.red_line_crossed = False
        self.passed = False
        self.passing_offset = 0.0  # ego's lateral offset when it passed (or last seen)
        self.opponent_reacted = False
        self.collided = False
        self.collision_partners: set[str] = set()
        #: per SUMO step: (time, ego_x, ego_y, opp_x, opp_y, SUMO collision partners of the ego)
        self.substeps: list[tuple[float, float, float, float, float, frozenset[str]]] = []

    def _begin_interaction(self) -> None:
        self._reset_interaction_flags()
        session = self.session or self._start_simulation()
        api = session.api
        with session.guard("restoring the start state"):
            api.simulation.loadState(self._state_file)
            # loadState rebuilds the vehicles: their TraCI settings are gone, re-apply them.
            for vid in (sc.EGO_ID, sc.OPPONENT_ID, sc.HAZARD_ID):
                api.vehicle.setSpeedMode(vid, 0)
                api.vehicle.setLaneChangeMode(vid, 0)
            api.vehicle.setSpeed(sc.EGO_ID, sc.EGO_SPEED)
            api.vehicle.setSpeed(sc.OPPONENT_ID, sc.OPPONENT_SPEED)
            api.vehicle.setSpeed(sc.HAZARD_ID, 0.0)
            self._read_positions()
        self.passing_offset = self.ego_y

    def _live_session(self) -> SumoSession:
        if self.session is None:
            raise RuntimeError(CLOSED)
        return self.session

    def _read_positions(self) -> None:
        vehicle = self._live_session().api.vehicle
        ex, ey = vehicle.getPosition(sc.EGO_ID)
        ox, oy = vehicle.getPosition(sc.OPPONENT_ID)
        self.ego_x, self.ego_y = ex - sc.EGO_START, ey - self._centre_y
        self.opp_x, self.opp_y = ox - sc.EGO_START, oy - self._centre_y

    def _apply_action(self, action: np.ndarray) -> float:
        session = self._live_session()
        api = session.api
        lateral_speed = float(action[0]) * EGO_LATERAL_SPEED
        collided_before = self.collided
        with session.guard("simulating a decision step"):
            for _ in range(DECISION_SUBSTEPS):
                target = np.clip(
                    self.ego_y + lateral_speed * sc.STEP_LENGTH,
                    -MAX_LATERAL_OFFSET,
                    MAX_LATERAL_OFFSET,
                )
                api.vehicle.changeSublane(sc.EGO_ID, float(target - self.ego_y))
                api.simulationStep()
                self._read_positions()
                partners = frozenset(
                    c.victim if c.collider == sc.EGO_ID else c.collider
                    for c in api.simulation.getCollisions()
                    if sc.EGO_ID in (c.collider, c.victim)
                )
                self._after_substep(float(api.simulation.getTime()), partners)
        self.passing_offset = self.passing_offset if self.passed else self.ego_y
        return -1.0 if self.collided and not collided_before else 0.0

    def _after_substep(self, time: float, partners: frozenset[str]) -> None:
        """Bookkeeping after one SUMO step: collisions, red line, passing, opponent's cut-in."""
        self.substeps.append((time, self.ego_x, self.ego_y, self.opp_x, self.opp_y, partners))
        if partners:
            self.collided = True
            self.collision_partners |= partners
        if not self.red_line_crossed and self.ego_x >= RED_LINE:
            self.red_line_crossed = True
            self.left_before_red_line = lane_of(self.ego_y) == LEFT
        gap = self.opp_x - self.ego_x
        if not self.passed and gap <= 0.0:
            self.passed = True
            self.passing_offset = self.ego_y
        if not self.opponent_reacted and gap <= REACTION_GAP:
            self.opponent_reacted = True
            offset = (self.target_lane - sc.CENTRE_LANE) * sc.LANE_WIDTH
            self._live_session().api.vehicle.changeSublane(sc.OPPONENT_ID, offset - self.opp_y)

    def _base_observation(self) -> np.ndarray:
        s = POSITION_SCALE
        w = sc.LANE_WIDTH
        return np.array(
            [self.ego_x / s, self.ego_y / w, self.opp_x / s, self.opp_y / w, self.time_fraction],
            np.float32,
        )

    def _info(self) -> dict[str, Any]:
        info = super()._info()
        info["collision"] = self.collided
        info["collision_partners"] = sorted(self.collision_partners)
        info["left_before_red_line"] = self.left_before_red_line
        info["ego_lane"] = lane_of(self.ego_y)
        return info

    def __getstate__(self) -> dict[str, Any]:
        """A copy or pickle of the task before its first reset (the simulation is a process's
        own: a running one cannot be copied; ``game_state()`` saves the game instead)."""
        if getattr(self, "session", None) is not None:
            raise TypeError(
                "a Driving task with a running SUMO simulation cannot be copied or pickled: copy "
                "it before its first reset, or save the game with game_state() and restore it "
                "into another task (reset(options={'restore': state}))"
            )
        return self.__dict__

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self._closed:  # said first: the base's checks would point to a reset, refused too
            raise RuntimeError(CLOSED)
        return super().step(action)

    def close(self) -> None:
        """Stop SUMO and release this process's libsumo simulation for a later environment."""
        self._closed = True
        session = getattr(self, "session", None)
        if session is not None:
            session.close()
            self.session = None
        super().close()


def next_target_lane(left_before_red_line: bool, passing_offset: float) -> int:
    """T^z: right after an early left merge, else the lane the ego passed in (never centre)."""
    if left_before_red_line:
        return RIGHT
    lane = lane_of(passing_offset)
    if lane == CENTRE:
        return LEFT if passing_offset >= 0.0 else RIGHT
    return lane
