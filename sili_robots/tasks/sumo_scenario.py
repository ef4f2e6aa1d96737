"""The SUMO files of the Driving task: a straight three-lane road, three vehicles, one config.

Everything is generated from plain SUMO XML written here; the network is built by the
``netconvert`` of the installed ``eclipse-sumo`` wheel on first use and cached (keyed by a hash of
the inputs and the SUMO version), so nothing is downloaded and no ``SUMO_HOME`` is needed: the
wheel's own directory is used. Generation writes to a temporary directory and renames it into
place, so parallel processes building the cache at the same time do not see half-written files.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

from sili_robots.cache import cache_dir

# -- geometry (metres, seconds); lanes are numbered 0 (right) .. 2 (left) as in SUMO
LANE_WIDTH = 3.2
NUM_LANES = 3
CENTRE_LANE = 1
ROAD_LENGTH = 800.0
EDGE_ID = "road"
VEHICLE_LENGTH = 5.0
VEHICLE_WIDTH = 1.8
EGO_ID = "ego"
OPPONENT_ID = "opponent"
HAZARD_ID = "hazard"
EGO_START = 50.0  # front bumper, along the road
OPPONENT_START = 110.0  # 60 m ahead of the ego
HAZARD_POSITION = 235.0  # front bumper of the stopped hazard in the centre lane
EGO_SPEED = 20.0
OPPONENT_SPEED = 10.0
OPPONENT_LATERAL_SPEED = 3.0  # the opponent's cut-in: maxSpeedLat of its vehicle type
STEP_LENGTH = 0.1  # SUMO step
LATERAL_RESOLUTION = 0.2  # sublane width: lateral motion is continuous, not lane-by-lane


@dataclass(frozen=True)
class ScenarioFiles:
    """Paths of the generated SUMO inputs."""

    directory: Path
    net: Path
    routes: Path
    config: Path


def sumo_home() -> Path:
    """The SUMO installation of the ``eclipse-sumo`` wheel (never the user's ``SUMO_HOME``)."""
    try:
        import sumo
    except ImportError as exc:  # pragma: no cover - the wheel is a hard dependency
        raise RuntimeError(
            "the Driving task needs the eclipse-sumo wheel: pip install eclipse-sumo==1.28.0"
        ) from exc
    return Path(sumo.SUMO_HOME)


def sumo_binary(name: str = "sumo") -> Path:
    """Path of a SUMO executable shipped in the wheel, e.g. ``sumo`` or ``netconvert``."""
    path = sumo_home() / "bin" / name
    if not path.is_file():
        raise RuntimeError(f"SUMO executable {name!r} not found in the eclipse-sumo wheel ({path})")
    return path


def sumo_env() -> dict[str, str]:
    """Environment for SUMO subprocesses: the wheel's ``SUMO_HOME`` (for its XML schemas)."""
    env = dict(os.environ)
    env["SUMO_HOME"] = str(sumo_home())
    return env


def sumo_version() -> str:
    try:
        from importlib.metadata import version

        return version("eclipse-sumo")
    except Exception:  # pragma: no cover - metadata missing in odd installs
        return "unknown"


# -- plain XML ---------------------------------------------------------------------------------
def nodes_xml() -> str:
    return (
        "<nodes>\n"
        '    <node id="start" x="0.00" y="0.00"/>\n'
        f'    <node id="end" x="{ROAD_LENGTH:.2f}" y="0.00"/>\n'
        "</nodes>\n"
    )


def edges_xml() -> str:
    return (
        "<edges>\n"
        f'    <edge id="{EDGE_ID}" from="start" to="end" numLanes="{NUM_LANES}" speed="40.00" '
        f'width="{LANE_WIDTH:.2f}"/>\n'
        "</edges>\n"
    )


def routes_xml() -> str:
    """Vehicle types and the three vehicles, all departing at t = 0 in the centre lane.

    The lane-change models are switched off in XML (``lcStrategic="-1"`` etc.) and lateral
    acceleration is effectively unbounded, so lateral motion follows the TraCI requests exactly;
    ``sigma="0"`` and ``speedDev="0"`` make the simulation deterministic.
    """
    common = (
        f'length="{VEHICLE_LENGTH:.2f}" width="{VEHICLE_WIDTH:.2f}" minGap="0.00" sigma="0" '
        'speedDev="0" lcStrategic="-1" lcCooperative="-1" lcSpeedGain="0" lcKeepRight="0" '
        'lcAccelLat="100" latAlignment="arbitrary"'
    )
    depart = f'departLane="{CENTRE_LANE}" insertionChecks="none" route="r" depart="0.00"'
    return (
        "<routes>\n"
        f'    <vType id="egoType" {common} maxSpeed="{EGO_SPEED + 10:.2f}" maxSpeedLat="10.00" '
        'color="0,0,1"/>\n'
        f'    <vType id="opponentType" {common} maxSpeed="{OPPONENT_SPEED:.2f}" '
        f'maxSpeedLat="{OPPONENT_LATERAL_SPEED:.2f}" color="1,0,0"/>\n'
        f'    <vType id="hazardType" {common} maxSpeed="1.00" maxSpeedLat="0.10" '
        'color="1,1,0"/>\n'
        f'    <route id="r" edges="{EDGE_ID}"/>\n'
        f'    <vehicle id="{HAZARD_ID}" type="hazardType" {depart} '
        f'departPos="{HAZARD_POSITION:.2f}" departSpeed="0.00"/>\n'
        f'    <vehicle id="{OPPONENT_ID}" type="opponentType" {depart} '
        f'departPos="{OPPONENT_START:.2f}" departSpeed="{OPPONENT_SPEED:.2f}"/>\n'
        f'    <vehicle id="{EGO_ID}" type="egoType" {depart} '
        f'departPos="{EGO_START:.2f}" departSpeed="{EGO_SPEED:.2f}"/>\n'
        "</routes>\n"
    )


def config_xml(net: str, routes: str) -> str:
    """SUMO options: sublane model, SUMO's own collision checks that warn and keep going."""
    return (
        "<configuration>\n"
        "    <input>\n"
        f'        <net-file value="{net}"/>\n'
        f'        <route-files value="{routes}"/>\n'
        "    </input>\n"
        "    <time>\n"
        '        <begin value="0"/>\n'
        f'        <step-length value="{STEP_LENGTH}"/>\n'
        "    </time>\n"
        "    <processing>\n"
        f'        <lateral-resolution value="{LATERAL_RESOLUTION}"/>\n'
        '        <collision.action value="warn"/>\n'
        '        <collision.check-junctions value="true"/>\n'
        '        <collision.mingap-factor value="0"/>\n'
        '        <time-to-teleport value="-1"/>\n'
        "    </processing>\n"
        "    <random_number>\n"
        '        <seed value="0"/>\n'
        "    </random_number>\n"
        "    <report>\n"
        '        <no-step-log value="true"/>\n'
        '        <no-warnings value="true"/>\n'
        '        <duration-log.disable value="true"/>\n'
        "    </report>\n"
        "</configuration>\n"
    )


# -- generation and cache ------------------------------------------------------------------------
def scenario_key() -> str:
    text = "\n".join([sumo_version(), nodes_xml(), edges_xml(), routes_xml(), config_xml("", "")])
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def scenario_files() -> ScenarioFiles:
    """Return the scenario's files, building them with the wheel's netconvert if not cached
    (in the package's cache, else the temporary folder)."""
    roots = [cache_dir() / "sumo", Path(tempfile.gettempdir()) / "sili-sumo"]
    errors = []
    for base in roots:
        target = base / scenario_key()
        files = _files_in(target)
        if files.config.is_file():
            return files
        try:
            _build(target)
            return files
        except OSError as exc:  # unwritable cache: try the next place
            errors.append(f"{base}: {exc}")
    raise RuntimeError("could not write the SUMO scenario files: " + "; ".join(errors))


def _files_in(directory: Path) -> ScenarioFiles:
    return ScenarioFiles(
        directory,
        directory / "road.net.xml",
        directory / "road.rou.xml",
        directory / "road.sumocfg",
    )


def _build(target: Path) -> None:
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=".build-", dir=target.parent))
    try:
        (tmp / "road.nod.xml").write_text(nodes_xml())
        (tmp / "road.edg.xml").write_text(edges_xml())
        cmd = [
            str(sumo_binary("netconvert")),
            "--node-files",
            "road.nod.xml",
            "--edge-files",
            "road.edg.xml",
            "--output-file",
            "road.net.xml",
            "--no-turnarounds",
            "true",
            "--no-warnings",
            "true",
        ]
        proc = subprocess.run(
            cmd, cwd=tmp, env=sumo_env(), capture_output=True, text=True, check=False
        )
        if proc.returncode != 0 or not (tmp / "road.net.xml").is_file():
            raise RuntimeError(
                f"netconvert failed (exit code {proc.returncode}): {proc.stderr.strip()}"
            )
        (tmp / "road.rou.xml").write_text(routes_xml())
        (tmp / "road.sumocfg").write_text(config_xml("road.net.xml", "road.rou.xml"))
        try:
            tmp.rename(target)
        except OSError:
            if not (target / "road.sumocfg").is_file():  # lost a race only if the winner finished
                raise
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
