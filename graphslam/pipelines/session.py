"""One visual session: what every command that runs a visual back end assembles
from a parsed config file and an image sequence, built in one place.

``graphslam run`` and ``graphslam compare`` on image sequences build a
:class:`VisualSetup` (the sequence, the config file and the settings every back
end of the run shares: odometry, its noise, the seed, the frame limit, the
detector), then one :class:`VisualSession` per back end (the back end with the
overrides the run implies, and its tracker), and call :meth:`VisualSession.run`.
``graphslam sweep`` runs ``graphslam run`` for each of its runs, so it goes
through the same entry. What a back end takes is read from the back-end table
(:mod:`graphslam.backend_table`), never from its name.

``graphslam localize`` (and ``graphslam run --map``, which places its first frame
in a saved map) runs no back end: it opens a :class:`LocaliseSession`, the map's
localiser on the sequence, its camera checked against the map's, then calls
:meth:`LocaliseSession.run`. It takes no odometry, so it needs none of
:class:`VisualSetup`'s settings.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from graphslam import registry
from graphslam.maps.files import check_camera
from graphslam.maps.spatial_map import SpatialMap
from graphslam.pipelines import localize_run
from graphslam.pipelines import spatial as vp
from graphslam.pipelines.localize import Localizer, make_localizer
from graphslam.sources.spatial.sequence import ImageSequence
from slamcore.config import ConfigFile
from slamcore.errors import ConfigError


@dataclass(frozen=True)
class VisualSetup:
    """What every back end of one visual command shares.

    Attributes:
        sequence: the image sequence.
        config: the parsed config file (front end and back-end sections).
        run_config: ``[visual]`` with the command line's ``--odometry`` on top.
        odometry_noise: ``[odometry_noise]`` with the seed and ``--odometry-noise``.
        mode: the odometry the runs use (``auto`` resolved).
        odometry: (N-1, 4, 4) that odometry, or None.
        seed: the command's ``--seed``, or None.
        max_frames: the frame limit, or None.
        detector: ``--frontend``, or None (the config's).
        no_polish: ``--no-polish``.
    """

    sequence: ImageSequence
    config: ConfigFile
    run_config: vp.VisualRunConfig
    odometry_noise: vp.OdometryNoiseConfig
    mode: str
    odometry: np.ndarray | None = field(repr=False, default=None)
    seed: int | None = None
    max_frames: int | None = None
    detector: str | None = None
    no_polish: bool = False

    @classmethod
    def read(
        cls,
        sequence: ImageSequence,
        config: ConfigFile,
        *,
        odometry: str | None = None,
        odometry_noise: tuple[float, float] | None = None,
        seed: int | None = None,
        max_frames: int | None = None,
        detector: str | None = None,
        no_polish: bool = False,
    ) -> VisualSetup:
        """The settings from ``config`` with the command line's on top (None: the file's);
        ``odometry_noise`` is ``(sigma_t_per_m, sigma_r_deg)``."""
        run_config = config.section(vp.VisualRunConfig, {"odometry": odometry})
        noise_over: dict[str, Any] = {"seed": seed}
        if odometry_noise is not None:
            noise_over.update(sigma_t_per_m=odometry_noise[0], sigma_r_deg=odometry_noise[1])
        noise = config.section(
            vp.OdometryNoiseConfig,
            noise_over,
            flags={
                "sigma_t_per_m": "--odometry-noise SIGMA_T_PER_M",
                "sigma_r_deg": "--odometry-noise SIGMA_R_DEG",
                "seed": "--seed",
            },
        )
        mode, odo, _, _ = vp.resolve_odometry(sequence, run_config.odometry, noise)
        own = getattr(sequence, "config", None)
        if mode != "sequence" and own is not None and hasattr(own, "ODOMETRY_KEYS"):
            # the synthetic sequence's odometry noise, unread under derived or no odometry
            config.mark_inert(
                own.SECTION, own.ODOMETRY_KEYS, "--odometry sequence (the sequence's own odometry)"
            )
        return cls(sequence, config, run_config, noise, mode, odo, seed, max_frames, detector, no_polish)

    def check_seed(self, backends: list[str], simulated: bool) -> None:
        """``--seed`` is refused, one line, where nothing it seeds is in the run: a
        recorded sequence (``simulated`` False), odometry not derived, and no back end
        of ``backends`` that draws random numbers."""
        if self.seed is None or simulated or self.mode == "derived":
            return
        if self.mode == "none":  # camera alone: iSAM2's bootstrap and PnP RANSACs draw
            silent = [self._draws_nothing(name) for name in backends]
            if all(silent):
                raise ConfigError(f"--seed has no effect here: {silent[0]}")
            return
        if not any(registry.visual_implementation(name).seeded for name in backends):
            who = f"{backends[0]} draws" if len(set(backends)) == 1 else "no back end draws"
            raise ConfigError(
                f"--seed has no effect here: the images are recorded, the odometry "
                f"is not derived and {who} no random numbers"
            )

    def _draws_nothing(self, name: str) -> str:
        """Why back end ``name``, as configured, draws no random number ("" if it does)."""
        config = self.config.section(registry.visual_backend_config(name))
        return getattr(config, "why_no_draws", "")

    def session(self, backend_name: str, overrides: dict | None = None) -> VisualSession:
        """The back end ``backend_name`` (``overrides`` on its config section) and its
        tracker, set up for this run."""
        overrides = {
            **(overrides or {}),
            **vp.backend_overrides(
                backend_name,
                self.mode,
                self.seed,
                self.no_polish,
                vp.scene_nearest_depth(self.sequence, self.config),
            ),
        }
        backend = registry.make_visual_backend(backend_name, config=self.config, overrides=overrides)
        settings = getattr(backend, "config", None)
        if self.mode != "none" and getattr(settings, "robot_model", None) == "constant_velocity":
            # refused before the first frame: it failed at the second, "interrupted"
            from slamcore.config import section_name

            section = section_name(type(settings))
            raise ConfigError(
                f'[{section}] robot_model = "constant_velocity" tracks by the camera alone, and '
                f"this run has odometry (--odometry {self.mode}): use --odometry none, or leave "
                "robot_model to the run",
                self.config.path,
                self.config.line_of(section, "robot_model"),
            )
        tracker_config, tracker = vp.make_tracker(self.config, backend, self.detector)
        return VisualSession(self, backend_name, backend, tracker_config, tracker)


@dataclass
class VisualSession:
    """One back end's run of a :class:`VisualSetup` (built by :meth:`VisualSetup.session`)."""

    setup: VisualSetup
    backend_name: str
    backend: Any
    tracker_config: Any
    tracker: Any

    def run(self, **kwargs) -> vp.VisualRunResult:
        """:func:`graphslam.pipelines.spatial.run` on the setup's sequence, settings and
        frame limit; ``kwargs``: its progress, hooks, loop closer and start pose."""
        s = self.setup
        return vp.run(
            s.sequence,
            self.backend,
            self.tracker,
            config=s.run_config,
            odometry_noise=s.odometry_noise,
            max_frames=s.max_frames,
            frontend=self.tracker_config.detector,
            **kwargs,
        )


@dataclass(frozen=True)
class LocaliseSession:
    """A saved map's localiser on one image sequence (module docstring)."""

    sequence: ImageSequence
    smap: SpatialMap
    localizer: Localizer

    @classmethod
    def open(
        cls, sequence: ImageSequence, config: ConfigFile, smap: SpatialMap, where: str
    ) -> LocaliseSession:
        """The localiser of ``smap`` (``[localize]``, ``[loop_pnp]``, ``[harris]``, ``[orb]``
        of ``config``) on ``sequence``. InputError (naming ``where``) when the sequence's
        camera is not the map's."""
        check_camera(smap, sequence.K, sequence.image_size, where, getattr(sequence, "distortion", None))
        return cls(sequence, smap, make_localizer(smap, sequence.K, config))

    def run(self, **kwargs) -> localize_run.LocalizeResult:
        """:func:`graphslam.pipelines.localize_run.run` on the sequence; ``kwargs``: its
        progress, frame hook and frame limit."""
        return localize_run.run(self.sequence, self.localizer, **kwargs)
