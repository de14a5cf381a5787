"""``nue view``: an episode in the browser — run live through the shared agent loop, or replayed from a record.

The viewer is Rerun's web viewer, served by the ``rerun-sdk`` wheel itself (no network needed). One
recording stream has up to two sinks: a gRPC server the page reads while the episode runs
(``ViewConfig.grpc_port``; the page itself on ``ViewConfig.port``) and an ``.rrd`` file that opens later
(``rerun rec.rrd``, or ``rerun --web-viewer rec.rrd`` for a browser). Both servers listen on
``ViewConfig.host``, the loopback unless asked otherwise (:mod:`nue.viz.view_server`). What is drawn:
:mod:`nue.viz.view_scene`; screenshots: :mod:`nue.viz.view_shot`.

A live run is :func:`nue.rollout.run_episode` with an ``on_step`` callback that logs each step (the
maps the policy saw, before the memory learns the frame; VGM's and NRNS's graphs, :mod:`nue.viz.view_graph`).
A replay reads the poses of a record's ``extra['trajectory']`` and re-renders the frames there; the policy does
not run, and the memory is re-run along the recorded poses only when asked (``ReplaySource.maps``). A replay finds
the record's episode file itself (:func:`find_episode`): the episode set whose file holds an episode with the record's digest.
"""

from __future__ import annotations

import dataclasses
import json
import re
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import rerun as rr

from nue.errors import ConfigError, DataError, EpisodeError
from nue.evaluate.record_keys import OnDropped, UniqueKeys, dropped_message
from nue.nerf.online import OnlineNeRF
from nue.policy.agent import ExpertAgent
from nue.policy.checkpoint import load_agent, load_header, load_memory
from nue.rollout import run_episode
from nue.scene.generator import SPLITS, ensure_house
from nue.scene.navgrid import NavGrid
from nue.scene.scene import Scene
from nue.sim.env import ImageNavEnv, make_env
from nue.sim.episodes import Episode, load_episodes
from nue.sim.record import EpisodeRecord, RecordFormatError
from nue.sim.task import get_task
from nue.viz.view_graph import GraphLogger
from nue.viz.view_scene import GOAL_COLOUR, TRAJECTORY_COLOUR, EpisodeLogger, SceneViewConfig, blueprint
from nue.viz.view_server import PageServer, check_port, grpc_url, is_loopback, page_url, url_host, wait_port_closed
from nue.viz.view_shot import find_chromium, has_colour, screenshot_page


@dataclass(frozen=True)
class ViewConfig:
    """Where the viewer serves and what it writes."""

    host: str = "127.0.0.1"
    """Interface the page and its data stream listen on: 127.0.0.1 = this machine only; an address of another
    interface, or 0.0.0.0 for every one, makes the run visible to anyone who can reach that interface."""
    port: int = 9090
    """Port of the web page."""
    grpc_port: int = 9876
    """Port of the data stream the page reads (Rerun's gRPC server)."""
    serve: bool = True
    """Serve the page; False only writes ``save``."""
    save: str | None = None
    """Also write the recording to this ``.rrd`` file."""
    scene: SceneViewConfig = SceneViewConfig()
    """What is drawn and how finely."""


@dataclass(frozen=True)
class LiveSource:
    """Run an episode now: a checkpoint's policy with its memory, or the geodesic expert with the memory alongside."""

    scene: str
    """Scene folder (Gibson layout)."""
    episodes: str
    """Episode file (any format ``nue`` reads)."""
    episode: str = "0"
    """Episode id, or its index in the file."""
    checkpoint: str | None = None
    """Policy checkpoint; None = the geodesic expert."""
    task: str = "paper"
    """Task preset."""
    seed: int = 0
    """Episode seed (memory ray sampling, action sampling)."""
    max_steps: int = 0
    """Override the preset's step limit (0 = keep it)."""


@dataclass(frozen=True)
class ReplaySource:
    """Replay a recorded episode from its stored trajectory, without running the policy."""

    records: tuple[str, ...]
    """Record files (JSON lines from ``nue eval`` / ``nue expert``)."""
    key: str
    """The record's ``extra['key']`` (``method/scene/episode_id``), or ``scene/episode_id``."""
    scenes_root: str = "data/scenes"
    """Where the record's scene folder is (validation houses are generated there if missing)."""
    episodes: str | None = None
    """Episode file holding the record's episode; default ``episodes_dir/<scene>.json``."""
    episodes_dir: str | None = None
    """Folder of per-house episode files, used when ``episodes`` is None; None: the folder under ``episodes/``
    whose ``<scene>.json`` holds the record's episode (:func:`find_episode`)."""
    task: str = "paper"
    """Task preset the record was made with."""
    maps: bool = False
    """Re-run the memory along the recorded poses to show I_u / I_cog (the policy still does not run)."""
    checkpoint: str | None = None
    """With ``maps``: take the memory's preset and initial weights from this checkpoint (default: ``fast``)."""
    drop_duplicates: bool = False
    """A records file with a key recorded twice is refused; with this, the first record of each key is used."""


# ----------------------------------------------------------------------------------------- serving
class Viewer:
    """A recording stream with its sinks (the page and its data stream on ``cfg.host``, and/or an ``.rrd`` file)."""

    def __init__(self, cfg: ViewConfig, name: str):
        if not cfg.serve and not cfg.save:
            raise ConfigError("--no-serve", "nothing to do: give --save FILE.rrd, or serve the page")
        if cfg.serve:
            check_port(cfg.port, "--port", cfg.host)
            check_port(cfg.grpc_port, "--grpc-port", cfg.host)
            if cfg.port == cfg.grpc_port:
                raise ConfigError("--grpc-port", "must differ from --port")
        self.cfg = cfg
        self.page: PageServer | None = None
        self.rec = rr.RecordingStream("nue", recording_id=name)
        sinks = []
        if cfg.serve:
            sinks.append(rr.GrpcServerSink(bind_ip=cfg.host, port=cfg.grpc_port))
        if cfg.save:
            Path(cfg.save).parent.mkdir(parents=True, exist_ok=True)
            sinks.append(rr.FileSink(str(cfg.save)))
        self.rec.set_sinks(*sinks, default_blueprint=blueprint())
        self.rec.send_recording_name(name)
        self.url = self.local_url = None
        """The page's address (for every interface: under this machine's name), and the one a browser here opens."""
        if cfg.serve:
            self.url = page_url(url_host(cfg.host), cfg.port, cfg.grpc_port)
            self.local_url = page_url(url_host(cfg.host, local=True), cfg.port, cfg.grpc_port)
            try:
                self.page = PageServer(cfg.host, cfg.port, grpc_url(url_host(cfg.host, local=True), cfg.grpc_port))
            except BaseException:
                self.rec.disconnect()
                raise

    @property
    def public(self) -> bool:
        """Whether the page and its data are served beyond this machine."""
        return self.cfg.serve and not is_loopback(self.cfg.host)

    def logger(self, env) -> EpisodeLogger:
        """A logger for the current episode of ``env`` (after its reset)."""
        log = EpisodeLogger(self.rec, env.task.camera, env.navgrid, env.floor_z, self.cfg.scene)
        log.begin(env.scene, env.goal_xy, env.goal_image, env.task.success_radius)
        return log

    def flush(self) -> None:
        """Send everything logged so far to the sinks."""
        self.rec.flush()

    def close(self) -> None:
        """Close the sinks: the ``.rrd`` file gets its footer, the gRPC server stops (the page loses its data), and
        the page server ends."""
        try:
            self.rec.flush()
            self.rec.disconnect()
            if self.cfg.serve:  # the gRPC server stops in the background: return once its port is free
                wait_port_closed(self.cfg.host, self.cfg.grpc_port)
        finally:
            if self.page is not None:
                self.page.close()


# ------------------------------------------------------------------------------------------ sources
def _task(name: str, max_steps: int = 0):
    task = get_task(name)
    return dataclasses.replace(task, max_steps=max_steps) if max_steps else task


def pick_episode(episodes: list, which: str, where) -> object:
    """The episode with id ``which``, else the one at index ``which``; :class:`EpisodeError` if neither."""
    for e in episodes:
        if e.episode_id == which:
            return e
    if which.isdigit() and int(which) < len(episodes):
        return episodes[int(which)]
    raise EpisodeError(where, f"no episode {which!r} (ids {', '.join(e.episode_id for e in episodes[:5])}"
                              f"{', ...' if len(episodes) > 5 else ''}; or an index below {len(episodes)})")


def _memory_from(checkpoint: str | None, camera):
    """The online NeRF memory: a checkpoint's preset and initial weights, else the ``fast`` preset."""
    return OnlineNeRF("fast", camera) if checkpoint is None else load_memory(checkpoint, camera)


def run_live(viewer: Viewer, src: LiveSource) -> EpisodeRecord:
    """Run ``src``'s episode through :func:`nue.rollout.run_episode`, logging every step; returns its record.
    The env and agent come from the shared setup path (:func:`nue.sim.env.make_env`,
    :func:`nue.policy.checkpoint.load_agent`); the expert gets the ``fast`` memory alongside, for the maps."""

    scene = Scene.load(src.scene)
    env = make_env(scene, src.task, max_steps=src.max_steps)
    episode = pick_episode(load_episodes(src.episodes, scene, env.task, navgrid=env.navgrid), src.episode, src.episodes)
    if src.checkpoint is None:
        agent, memory, method = ExpertAgent(), _memory_from(None, env.task.camera), "expert"
    else:
        agent, memory = load_agent(src.checkpoint, env.task, scenes={scene.name: scene.content_hash})
        method = load_header(src.checkpoint).name
    log: list[EpisodeLogger] = []
    graph: list[GraphLogger] = []

    def on_step(s) -> None:
        if s.t == 0:
            log.append(viewer.logger(s.env))
            graph.append(GraphLogger(log[0].rec, log[0].floor_z))
        log[0].step(s.t, s.obs["pose"], s.obs["rgb"], s.obs["depth"], s.maps, s.info.get("geodesic_distance"))
        graph[0].log(agent, s.obs["pose"])  # VGM's and NRNS's graphs; nothing for other agents

    record = run_episode(env, agent, episode=episode, memory=memory, seed=src.seed, on_step=on_step, method=method)
    final = env.trajectory_so_far().poses[-1]
    rgb, depth = env.renderer.render(final, env.floor_z)
    log[0].step(record.steps, final, rgb, depth, None, record.final_geodesic)
    return record


def find_record(paths, key: str, drop_duplicates: bool = False, on_dropped: OnDropped | None = None) -> EpisodeRecord:
    """The record whose ``extra['key']`` or ``method/scene/episode_id`` (the method as RESULTS.md names it: records
    renamed after their run, ``nue_v2``, keep the key ``nue/...`` of that run) is ``key`` or ends in ``/key``; where
    several match, the ones whose ``method/scene/episode_id`` is ``key``; :class:`DataError` if none or still several.
    A file holding a key twice is refused (:mod:`nue.evaluate.record_keys`), or with ``drop_duplicates`` read
    with the first record of each key (``on_dropped(file, n)`` is told how many were left out)."""

    hits, n = [], 0
    for path in paths:
        unique = UniqueKeys(path, drop_duplicates)
        for i, line in enumerate(Path(path).read_text().splitlines(), 1):
            if not line.strip():
                continue
            try:
                d = json.loads(line)
                named = f"{d['method']}/{d['scene']}/{d['episode_id']}"
                k = d.get("extra", {}).get("key") or named
            except (ValueError, KeyError, TypeError, AttributeError):
                raise DataError(path, f"line {i} is not an episode record") from None
            if not unique.first(d, i):
                continue
            n += 1
            if any(x == key or x.endswith("/" + key) for x in (k, named)):
                hits.append((named, d))
        unique.report(on_dropped)
    if len(hits) > 1:
        hits = [h for h in hits if h[0] == key] or hits
    if len(hits) != 1:
        why = "no record" if not hits else f"{len(hits)} records ({', '.join(k for k, _ in hits[:3])})"
        raise DataError(paths[0] if len(paths) == 1 else "--records", f"{why} with key {key!r} among {n}")
    try:
        return EpisodeRecord.from_dict(hits[0][1])
    except RecordFormatError as exc:
        raise DataError(paths[0] if len(paths) == 1 else "--records", f"{key}: {exc}") from None


def episode_files(record_files, scene: str, roots=(Path("episodes"),)) -> list[Path]:
    """The files ``<root>/<set>/<scene>.json`` that may hold a record's episode, in the order :func:`find_episode`
    tries them: the sets a record file's name ends in first (``records_val252.jsonl``, ``val252+swap.jsonl`` ->
    ``val252``; ``records_val_plain.jsonl`` -> ``val_plain``), then ``val``, then the other sets by name. The sets
    are the folders under ``roots`` (default ``episodes/``) and under the ``episodes/`` folder nearest above each
    record file (``results/x.jsonl`` -> ``episodes/`` of its repository)."""

    folders: list[Path] = []
    for root in [*roots, *(_repository_episodes(f) for f in record_files)]:
        if root is not None and root.is_dir() and all(root.resolve() != f.resolve() for f in folders):
            folders.append(root)
    sets = [d for root in folders for d in sorted(root.iterdir()) if (d / f"{scene}.json").is_file()]
    stems = [Path(f).name.split(".")[0].split("+")[0] for f in record_files]

    def named(d: Path) -> bool:
        return any(re.search(rf"(^|_){re.escape(d.name)}$", stem) for stem in stems)

    ordered = sorted(sets, key=lambda d: (not named(d), d.name != "val", d.name))
    return [d / f"{scene}.json" for d in ordered]


def _repository_episodes(record_file) -> Path | None:
    """``<repo>/episodes`` of the nearest folder above ``record_file`` that has one, else None."""
    for parent in Path(record_file).resolve().parents:
        if (parent / "episodes").is_dir():
            return parent / "episodes"
    return None


def find_episode(record: EpisodeRecord, record_files, scene: Scene, task, nav: NavGrid,
                 roots=(Path("episodes"),)) -> Episode:
    """The episode a record was made on, from the episode sets under ``roots`` (:func:`episode_files`): the first
    file whose episode with the record's id has the record's digest (``extra['settings']['episode']``,
    :meth:`nue.evaluate.eval_job.RunSettings.episode_digest`); a record without a digest (``nue expert``, older
    records) takes the first file holding its id. :class:`EpisodeError` naming the files tried if none does."""

    from nue.evaluate.eval_job import RunSettings

    digest = (record.extra.get("settings") or {}).get("episode")
    tried = episode_files(record_files, record.scene, roots)
    for path in tried:
        try:
            episodes = load_episodes(path, scene, task, navgrid=nav)
        except EpisodeError:
            continue  # another task's or another house's file: not this record's
        for e in episodes:
            if e.episode_id == record.episode_id and (digest is None or RunSettings.episode_digest(e) == digest):
                return e
    what = f"episode {record.episode_id!r}" + (f" with digest {digest}" if digest else "")
    where = ", ".join(str(p) for p in tried) or f"no {record.scene}.json under {', '.join(str(r) for r in roots)}"
    raise EpisodeError(record.scene, f"no episode file holds the record's {what} (tried {where}); "
                                     "give --episodes FILE or --episodes-dir DIR")


def run_replay(viewer: Viewer, src: ReplaySource, on_dropped: OnDropped | None = None) -> np.ndarray:
    """Log the recorded episode at its recorded poses; returns those poses (T + 1, 3)."""

    record = find_record(src.records, src.key, src.drop_duplicates, on_dropped)
    traj = record.trajectory()
    if traj is None:
        raise DataError(src.key, "the record keeps no per-step trajectory (made before trajectories were stored)")
    folder = Path(src.scenes_root) / record.scene
    split, _, index = record.scene.rpartition("_")
    if not folder.exists() and split in SPLITS and index.isdigit():
        folder = ensure_house(split, int(index), src.scenes_root)
    scene = Scene.load(folder)
    task = _task(src.task)
    nav = NavGrid.from_scene(scene)
    if src.episodes or src.episodes_dir:
        ep_file = src.episodes or str(Path(src.episodes_dir) / f"{record.scene}.json")
        episode = pick_episode(load_episodes(ep_file, scene, task, navgrid=nav), record.episode_id, ep_file)
    else:
        episode = find_episode(record, src.records, scene, task, nav)
    env = ImageNavEnv(scene, task, [episode], navgrid=nav)
    env.reset(seed=0, options={"episode": episode})
    log = viewer.logger(env)
    seed = int(record.extra.get("seed", 0))
    memory = _memory_from(src.checkpoint, task.camera) if src.maps else None
    if memory is not None:
        memory.reset(seed, start_pose=traj.poses[0], floor_z=env.floor_z)
    field = nav.distance_field(env.nav_goal_xy)
    for t, pose in enumerate(traj.poses):
        rgb, depth = env.renderer.render(pose, env.floor_z)
        maps = memory.render_maps(pose, depth[..., None], floor_z=env.floor_z) if memory is not None else None
        log.step(t, pose, rgb, depth, maps, nav.lookup(field, pose[:2]))
        if memory is not None:
            memory.step(rgb, depth[..., None], pose, floor_z=env.floor_z)
    return traj.poses


def view(cfg: ViewConfig, source: LiveSource | ReplaySource, screenshot: str | None = None,
         serve_seconds: float = 0.0, screenshot_timeout: float = 120.0, echo=print) -> None:
    """Serve / save one episode; with ``screenshot``, write a PNG of the page after the episode (waiting at
    most ``screenshot_timeout`` s for the page) and return (after ``serve_seconds`` more, if given); else
    keep serving for ``serve_seconds`` (0 = until Ctrl-C)."""

    if screenshot and not cfg.serve:
        raise ConfigError("--screenshot", "needs the page: drop --no-serve")
    if screenshot and find_chromium() is None:
        raise ConfigError("--screenshot", "needs chromium on PATH (apt-get install chromium)")
    name = source.key if isinstance(source, ReplaySource) else f"{Path(source.scene).name}/{source.episode}"
    viewer = Viewer(cfg, name)
    try:
        if viewer.url:
            echo(f"viewer: {viewer.url}")
        if viewer.public:
            echo(f"viewer: listening on {cfg.host}, so the page and the run's data (ports {cfg.port} and "
                 f"{cfg.grpc_port}) are reachable from the network by anyone who can reach this machine")
        if isinstance(source, ReplaySource):
            poses = run_replay(viewer, source, on_dropped=lambda path, k: echo(dropped_message(path, k)))
            echo(f"replayed {source.key}: {len(poses) - 1} steps")
        else:
            rec = run_live(viewer, source)
            echo(f"{rec.method}: {'success' if rec.success else 'failure'} in {rec.steps} steps, "
                 f"path {rec.path_length:.2f} m")
        viewer.flush()
        if screenshot:
            def drawn(px) -> bool:  # the goal marker or the trajectory below the header bar (whose warnings are orange)
                body = px[px.shape[0] // 20:]
                return has_colour(body, TRAJECTORY_COLOUR) or has_colour(body, GOAL_COLOUR)

            try:
                seconds = screenshot_page(viewer.local_url, screenshot, timeout=screenshot_timeout, ready=drawn)
            except TimeoutError as exc:
                raise ConfigError("--screenshot", str(exc)) from None
            echo(f"screenshot: {screenshot} (page ready after {seconds:.1f} s)")
        if cfg.serve and (serve_seconds > 0 or not screenshot):
            if serve_seconds > 0:
                time.sleep(serve_seconds)
            else:
                echo("serving; Ctrl-C to stop")
                while True:
                    time.sleep(3600)
    except KeyboardInterrupt:
        pass
    finally:
        viewer.close()
    if cfg.save:
        echo(f"recording: {cfg.save} (open later with: rerun {cfg.save})")
