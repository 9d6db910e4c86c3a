"""The mismatch analysis: predict, locate, name (fit and rank every candidate), model, show.

:func:`analyse` runs the whole method on real frames and returns an :class:`Analysis`; the
report module renders it. Naming is greedy: every candidate is fitted on the training pixels and
scored on the held-out ones; the best is kept if significant, then the search repeats on the
remaining residual (up to ``max_effects``). ``none`` is the answer when no candidate is.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from scipy import stats

from ..errors import MismatchError
from ..frame import ToFFrame
from ..sim.tof import ToFConfig
from .concentration import (
    CONCENTRATED_EFFECTS,
    MIN_GROUPS,
    SIGNATURE_EFFECTS,
    group_levels,
)
from .data import camera_motion, check_frames, split_frames
from .features import DESCRIPTORS, all_descriptors, edge_jump_mm
from .fit import (
    CANDIDATES,
    FitResult,
    Problem,
    camera_moves,
    fit_effect,
    free_params,
    joint_fit,
    plain_params,
    score_fit,
)
from .frame_levels import FRAME_LEVEL_EFFECTS, frame_levels
from .likelihood import REFERENCE_NOISE_MM, tile_t_statistic, total_sigma
from .locate import locate, strata, stratum_facts
from .predict import FramePredictor
from .profile import (
    ALBEDO_EFFECT,
    CAMERA_WINDOW_REASONS,
    CAMERA_WINDOWS,
    PROFILE_EFFECTS,
    adopt_recording,
    albedo_from_interreflection,
    describe_profile,
)
from .specular import specular_masks
from .wording import phrase

_log = logging.getLogger(__name__)

#: a candidate is significant when its score (millinats per held-out pixel, after the
#: complexity penalty) and its tile t-statistic both exceed these. 15 mnats/px is a practical
#: threshold: a Gaussian residual gains ½δ² per pixel from removing a systematic error of δσ,
#: so it asks for ~0.17σ RMS explained, or a noise law ~13 % off (log s − (1 − 1/s²)/2)
MIN_SCORE = 15.0
MIN_T = 3.0
#: rounds after a scene, pose or timing effect is named judge what that fit left behind, which
#: includes its own imperfections: a second such effect must explain clearly more. The camera's
#: profile does not raise the bar: it is refitted beside every later candidate, and judged at
#: 20 after it, true first effects of 15-20 were left unnamed (session 25, docs/mismatch.md)
MIN_SCORE_LATER = 20.0
#: parsimony: among candidates scoring within this fraction of the best, the one with the fewest
#: parameters is preferred (a richer effect can mimic a simpler one, e.g. subsurface blur with
#: no delay is a mixed-pixel blur)
PARSIMONY = 0.15
#: ...unless the richer leader is better by this fraction of its score *and* significantly so
#: on the held-out tiles (paired t)
MIN_RICHER_GAIN = 0.01
MIN_PAIRED_T = 3.0
#: a richer effect fitted in the limit where its own physics vanishes *is* the simpler effect:
#: subsurface scattering whose delayed share shifts the range by less than this (fraction ×
#: delay, mm) is only a blur of the phasor, i.e. a pixel-footprint (mixed-pixel) effect
SUBSURFACE_MIN_SHIFT_MM = 1.0
NESTED: dict[str, tuple[str, Callable[[dict[str, float]], bool]]] = {
    "subsurface": ("mixed_pixels",
                   lambda p: p.get("fraction", 0.0) * p.get("delay_mm", 0.0)
                   < SUBSURFACE_MIN_SHIFT_MM),
}
#: the profile's refit beside a candidate: sweeps (the profile and the candidate jointly, then
#: the noise law) until one gains less than REFIT_TOL nats per training pixel (1 mnat/px, a
#: fifteenth of MIN_SCORE), at most REFIT_SWEEPS
REFIT_SWEEPS = 4
REFIT_TOL = 1e-3
#: "interior" metrics leave out pixels this close to a depth edge (px), where flying pixels and
#: the reference's own edge errors dominate whatever the model
INTERIOR_EDGE_PX = 2.0


@dataclass
class Analysis:
    """Result of :func:`analyse` (arrays are per held-out frame).

    Attributes:
        selected: effects found, strongest first (empty = no significant mismatch): scene,
            pose and timing physics in the one-shot workflow (the camera's profile is
            ``profile``); everything that changed, the profile included, when monitoring.
        rounds: per greedy round, every candidate's fit, best score first.
        evidence: effect -> evidence in words (from the first round it was ranked in).
        config_before, config_after: the simulator config given and the fitted one.
        metrics: held-out RMSE / MAE / excess RMSE before and after, pixel counts.
        location: :func:`.locate.locate` of the residual before modelling (all frames).
        test_frames: indices of the held-out frames shown.
        residual_before, residual_after: (H, W) float64 real − predicted range, mm.
        sigma_before, sigma_after: (H, W) float64 predicted residual std, mm.
        workflow: ``"one-shot"`` (no config given: the camera's profile is fitted first) or
            ``"monitor"`` (a config from an earlier run: only what changed since).
        profile: the camera's profile in the one-shot workflow: what of the camera refitted
            beside the candidates (the profile's takes, or the whole camera,
            :meth:`_Search.try_whole_camera`) pays in the final model; the takes first.
        profile_facts: what the recording states, the amplitude units chosen, the RMS of the
            camera's fixed pattern (``pattern_rms_mm``) and the share of the measured pixels
            left out as specular (``specular_share``, :mod:`.specular`)
            (:func:`.profile.adopt_recording`).
        profile_words: the camera's profile in words, relative to the nominal cell.
        unexplained: candidates that fitted best but are not taken, with why (``case``: a
            parameter at the ``"edge"`` of its range, the model does not explain this; a fit
            inside the ``"camera_window"``; a gain of interreflection that does not explain
            the residual where its own correction is large, ``"signature"``), and profile
            effects that ended at the edge of their range (``"profile_edge"``), each with
            where the residual sits.
        frame_levels: "round:effect" -> the held-out frames' residual levels before and after
            a candidate of one offset per frame, judged on them (:mod:`.frame_levels`).
        concentration: "round:effect" -> the held-out residual where a concentrated
            candidate's (or a ``SIGNATURE_EFFECTS`` one's) correction is large, before and
            after it (:mod:`.concentration`).
    """

    selected: list[str]
    rounds: list[list[FitResult]]
    evidence: dict[str, str]
    config_before: ToFConfig
    config_after: ToFConfig
    metrics: dict[str, float]
    location: dict[str, Any]
    test_frames: list[int]
    residual_before: list[np.ndarray] = field(default_factory=list)
    residual_after: list[np.ndarray] = field(default_factory=list)
    sigma_before: list[np.ndarray] = field(default_factory=list)
    sigma_after: list[np.ndarray] = field(default_factory=list)
    workflow: str = "one-shot"
    profile: list[str] = field(default_factory=list)
    profile_facts: dict[str, Any] = field(default_factory=dict)
    profile_words: list[str] = field(default_factory=list)
    unexplained: list[dict[str, Any]] = field(default_factory=list)
    frame_levels: dict[str, dict[str, Any]] = field(default_factory=dict)
    concentration: dict[str, dict[str, Any]] = field(default_factory=dict)

    @property
    def parameters(self) -> dict[str, dict[str, float]]:
        """Fitted parameters of every effect taken (profile and selected), as in the final
        model (a later round may have refitted the profile)."""
        return {e: plain_params(self.config_after, e)
                for e in dict.fromkeys([*self.profile, *self.selected])}

    def ranking(self) -> list[dict[str, Any]]:
        """First-round ranking (then later rounds' winners), JSON-ready."""
        rows = []
        for k, rnd in enumerate(self.rounds):
            for r in rnd:
                rows.append({"round": k + 1, "effect": r.effect, "score": round(r.score, 3),
                             "t": round(r.t_stat, 2), "n_params": r.n_params,
                             "test_gain_mnats": round(1000 * r.test_gain, 3),
                             "penalty_mnats": round(1000 * r.penalty, 3),
                             "parameters": r.parameters,
                             "evidence": self.evidence.get(f"{k + 1}:{r.effect}", r.note),
                             **({"frame_levels": self.frame_levels[key]}
                                if (key := f"{k + 1}:{r.effect}") in self.frame_levels else {}),
                             **({"concentration": self.concentration[key]}
                                if key in self.concentration else {})})
        return rows


def paired_t(problem: Problem, rich: FitResult, simple: FitResult) -> float:
    """Tile t-statistic of how much better ``rich`` fits the held-out pixels than ``simple``."""
    frames = problem.frames_of("test")
    masks = problem.masks("test")
    gain = [problem.cost_map(i, simple.config) - problem.cost_map(i, rich.config)
            for i in frames]
    return tile_t_statistic(gain, [masks[i] for i in frames])


def rank(results: list[FitResult], problem: Problem | None = None) -> list[FitResult]:
    """Best score first, with Occam's razor: a candidate with fewer parameters scoring within
    ``PARSIMONY`` of the leader takes the lead unless the leader fits the held-out pixels
    clearly better (by ``MIN_RICHER_GAIN`` of its score, with paired tile t >=
    ``MIN_PAIRED_T``); a richer effect can mimic a simpler one. A leader fitted in the limit
    where it reduces to a simpler candidate (``NESTED``: subsurface with no delay is a
    mixed-pixel blur) yields to that candidate when it scores within ``PARSIMONY``."""
    ordered = sorted(results, key=lambda r: -r.score)
    if not ordered or ordered[0].score <= 0:
        return ordered
    lead = ordered[0]
    if lead.effect in NESTED:
        simpler, degenerate = NESTED[lead.effect]
        alt = [r for r in ordered if r.effect == simpler and not r.note
               and r.score >= (1.0 - PARSIMONY) * lead.score]
        if alt and degenerate(lead.parameters):
            lead = alt[0]
            return [lead] + [r for r in ordered if r is not lead]
    for r in sorted(ordered, key=lambda r: (r.n_params, -r.score)):
        if (r is lead or r.note or r.n_params >= lead.n_params
                or r.score < (1.0 - PARSIMONY) * lead.score):
            continue
        clearly_better = (lead.score - r.score > MIN_RICHER_GAIN * lead.score
                          and problem is not None and paired_t(problem, lead, r) >= MIN_PAIRED_T)
        if not clearly_better:
            lead = r
            break
    return [lead] + [r for r in ordered if r is not lead]


def _significant(r: FitResult, min_score: float, min_t: float) -> bool:
    return r.score > min_score and r.t_stat > min_t and not r.note


def analyse(frames: Sequence[ToFFrame], config: ToFConfig | None = None, *,
            max_effects: int = 2, candidates: Sequence[str] = CANDIDATES,
            reference_noise_mm: float = REFERENCE_NOISE_MM, min_score: float = MIN_SCORE,
            min_t: float = MIN_T, edge_exclusion_px: float = 0.0,
            progress: Callable[[str], None] | None = None,
            monitor: bool | None = None) -> Analysis:
    """Locate, name, model and show the sim-vs-real mismatch of ``frames``.

    Two workflows. *One-shot* (``config`` None): the recording's modulation frequency and the
    amplitude units are adopted (:func:`.profile.adopt_recording`), the camera's profile
    (:data:`.profile.PROFILE_EFFECTS`) is fitted first and reported apart, and the scene, pose
    and timing physics is named on top of it (``selected``), each candidate judged with the
    camera's level free, the whole camera refitted with it and scored against the whole camera
    refitted without it. *Calibrate-then-monitor*
    (``config`` from an earlier run's ``fitted_config.json``): every candidate, the profile's
    included, is ranked against that config, so ``selected`` holds what changed since, and is
    empty when nothing did.

    Args:
        frames: real frames with references (one camera).
        config: the simulator configuration to diagnose (None = one-shot from the nominal
            cell).
        max_effects: most effects to select (greedy).
        candidates: effect names to consider.
        reference_noise_mm: std of the reference range, mm.
        min_score, min_t: significance thresholds (see ``MIN_SCORE``, ``MIN_T``).
        edge_exclusion_px: pixels closer than this to a reference depth edge are not used
            (1 = the edge pixels themselves; 0 = use every pixel).
        progress: called with a short message after each fitted candidate.
        monitor: the workflow: None = monitor when ``config`` is given, one-shot when not;
            False = one-shot starting from ``config`` (a stand-in for a known kind of camera:
            what it states about the camera is kept, its units and profile are not trusted).

    Raises:
        MismatchError: no frames, missing references, or nothing to compare.
    """
    check_frames(frames)
    monitor = config is not None if monitor is None else bool(monitor)
    if monitor and config is None:
        raise MismatchError("the monitor workflow needs the config of an earlier run")
    given = ToFConfig.nominal() if config is None else config
    base, facts = adopt_recording(frames, given, keep_units=monitor)
    # a surface brighter from one view than from another is not Lambertian: the predictor's
    # transport cannot light it, so it is left out and counted (:mod:`.specular`)
    specular = specular_masks(frames)
    facts = {**facts, "specular_share": _share(specular, frames)}
    problem, descriptors = build_problem(frames, base, reference_noise_mm, edge_exclusion_px,
                                         specular)
    predictors = problem.predictors
    residual0, sigma0 = _residuals(problem, None)
    location = locate(descriptors, residual0, sigma0)
    # the camera's own fixed pattern (:meth:`_Search.measure_pattern`): when monitoring, the
    # given noise law is the one measured beside it, so it is projected out from the start
    moving = camera_moves(problem.predictors)
    problem = problem.judged(free_pattern=monitor and moving)

    search = _Search(problem, descriptors, location, min_score, min_t, progress,
                     units_assumed=not monitor)
    scene = list(candidates) if monitor else _camera_first(search, candidates)
    # what the camera has but was not significant beside nothing else may be once the windows
    # and the physics are fitted: it competes again, and joins the profile if it wins (none
    # is left when the whole camera is refitted)
    rejoin = [] if monitor else [c for c in candidates if c in PROFILE_EFFECTS
                                 and c not in search.refit]
    selected = search.greedy(scene + rejoin, max_effects, rejoin=rejoin) \
        if max_effects > 0 else []
    # the camera's profile is what of the camera refitted pays in the final model (``refit``
    # holds the profile's takes first, then what joined or the rest of the whole camera): a
    # take of the profile's rounds may have given back what it held to the physics on top;
    # with the whole camera refitted, an effect those rounds left may pay beside it.
    # Interreflection beyond the albedo's doubt is named physics, no longer the profile's
    profile = search.confirm([e for e in search.refit if e not in selected], base)
    if not monitor and moving and "noise_model" in candidates:
        profile = search.measure_pattern(profile)
    search.flag_profile_edges(profile)
    pattern = search.problem.fixed_pattern(None)
    facts = {**facts, "pattern_rms_mm": 0.0 if pattern is None else pattern.rms_mm}
    if ALBEDO_EFFECT in profile:
        facts = {**facts, **albedo_from_interreflection(
            facts, float(search.problem.base.params(ALBEDO_EFFECT)["gain"]))}
    analysis = _finish(search.problem, given, selected, search.rounds, search.evidence,
                       location, predictors, descriptors)
    analysis.workflow = "monitor" if monitor else "one-shot"
    analysis.profile = profile
    analysis.profile_facts = facts
    analysis.profile_words = describe_profile(ToFConfig.nominal(), search.problem.base, facts,
                                              profile)
    analysis.unexplained = search.unexplained
    analysis.frame_levels = search.frame_levels
    analysis.concentration = search.concentration
    return analysis


def build_problem(frames: Sequence[ToFFrame], base: ToFConfig,
                  reference_noise_mm: float = REFERENCE_NOISE_MM,
                  edge_exclusion_px: float = 0.0,
                  specular: Sequence[np.ndarray] | None = None,
                  ) -> tuple[Problem, list[dict[str, np.ndarray]]]:
    """The fitting problem of ``frames`` predicted from ``base`` (split, usable pixels, edge
    jumps) and every frame's pixel descriptors; ``specular``: per frame, (H, W) bool pixels
    left out as well (:func:`.specular.specular_masks`).

    Raises:
        MismatchError: no pixel has both a real range and a predicted one.
    """
    motions = camera_motion(frames)
    predictors = [FramePredictor(f, base, frame_index=i, motion=m)
                  for i, (f, m) in enumerate(zip(frames, motions, strict=True))]
    real = [np.asarray(f.range_mm, dtype=np.float64) for f in frames]
    descriptors = all_descriptors(predictors, motions)
    # pixels on a reference depth edge are left out of fits and scores: one reference sample
    # cannot say where inside the pixel the edge lies, so their prediction is unreliable
    usable = [np.isfinite(r) & np.isfinite(p.predict().range_mm)
              & (d["edge_distance_px"] >= edge_exclusion_px)
              for r, p, d in zip(real, predictors, descriptors, strict=True)]
    if specular is not None:
        usable = [u & ~s for u, s in zip(usable, specular, strict=True)]
    if not any(u.any() for u in usable):
        raise MismatchError("no pixel has both a real range and a predicted one")
    jumps = [edge_jump_mm(f.reference_mm) for f in frames]
    problem = Problem(real, predictors, split_frames(frames), usable, reference_noise_mm, jumps)
    return problem, descriptors


def _camera_first(search: _Search, candidates: Sequence[str]) -> list[str]:
    """One-shot: name the camera's profile first (what every camera has its own values of,
    then what it has within a window), then leave the level free for the physics on top.
    The profile's takes lead ``search.refit``. Returns the candidates left for the scene
    rounds."""
    own = [c for c in candidates if c in PROFILE_EFFECTS]
    search.profile_start = search.problem.base
    profile = search.greedy(own, len(own), profile=True)
    # the camera's level stays a free profile parameter while physics is named on top
    search.problem = search.problem.judged(free_level=True)
    search.refit = profile
    search.converge_profile()
    # what the camera has its own value of within a window (the scene's albedo, known only
    # within the grey world's doubt, sets the interreflection's strength; the lens its blur)
    # is part of the profile; left in the residual, other effects would absorb it. Fitted
    # with the level free: interreflection lifts every range a little
    windows = [c for c in candidates if c in CAMERA_WINDOWS]
    search.profile_boxes = {c: window_box(c) for c in windows}
    profile += search.greedy(windows, len(windows), boxes=search.profile_boxes, profile=True)
    search.refit = profile
    search.converge_profile()
    search.try_whole_camera([*own, *windows])
    search.camera = [*own, *windows]
    return [c for c in candidates if c not in PROFILE_EFFECTS]


@dataclass
class _Search:
    """Greedy naming over rounds that share one growing model (see :func:`analyse`)."""

    problem: Problem
    descriptors: Sequence[dict[str, np.ndarray]]
    location: dict[str, Any]
    min_score: float
    min_t: float
    progress: Callable[[str], None] | None
    rounds: list[list[FitResult]] = field(default_factory=list)
    evidence: dict[str, str] = field(default_factory=dict)
    unexplained: list[dict[str, Any]] = field(default_factory=list)
    #: effects refitted with every later candidate (the camera's profile)
    refit: list[str] = field(default_factory=list)
    #: every effect taken so far, in order
    taken: list[str] = field(default_factory=list)
    #: the scene, pose and timing effects named so far (not the profile's; see MIN_SCORE_LATER)
    named: list[str] = field(default_factory=list)
    #: profile effects that joined the profile in a scene round (see :meth:`greedy`)
    joined: list[str] = field(default_factory=list)
    #: one-shot: the amplitude units were chosen by the grey world, so albedo, hence the
    #: interreflection's strength, is known only within ``UNITS_DOUBT``, and the camera's own
    #: values (its windows) are the profile's
    units_assumed: bool = False
    #: unit-box limits of profile effects searched in part of their range (the camera's
    #: windows: the albedo's interreflection, the lens's blur)
    profile_boxes: dict[str, list[tuple[float, float]]] = field(default_factory=dict)
    #: one-shot: the model before the camera's profile was fitted (its values are where a
    #: candidate's second descent restarts the profile, :meth:`_with_refit`)
    profile_start: ToFConfig | None = None
    #: one-shot: the whole camera (every profile effect and window, taken or not), refitted
    #: with each scene candidate and without it (:meth:`_camera_refitted`)
    camera: list[str] = field(default_factory=list)
    #: "round:effect" -> the held-out frames' levels of a candidate judged on them
    frame_levels: dict[str, dict[str, Any]] = field(default_factory=dict)
    #: "round:effect" -> where a concentrated candidate's correction is large, the held-out
    #: residual before and after it
    concentration: dict[str, dict[str, Any]] = field(default_factory=dict)

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W) of the smallest frame: what every frame resolves (:func:`resolved_box`)."""
        return min((m.shape for m in self.problem.real_mm), key=min)

    def greedy(self, candidates: Sequence[str], limit: int,
               boxes: dict[str, list[tuple[float, float]]] | None = None,
               rejoin: Collection[str] = (), profile: bool = False) -> list[str]:
        """Take up to ``limit`` of ``candidates``, one per round, while one is significant
        (``boxes``: candidates searched in part of their range). A winner in ``rejoin`` (a
        profile effect not significant in the profile's own rounds) joins the profile
        (``joined``, refitted from then on) instead of being named, and does not count.
        ``profile``: the takes are the camera's profile, which does not raise the threshold
        of later rounds (``MIN_SCORE_LATER``); any other take does (when monitoring, a changed
        profile effect too: nothing is refitted there)."""
        boxes = boxes or {}
        taken: list[str] = []
        used: list[str] = []
        while len(taken) < limit:
            k = len(self.rounds)
            # a scene round is judged over the whole camera refitted without its candidates
            before = None if profile else self._camera_refitted()
            results = []
            for name in candidates:
                # the camera's own effects are refitted with every candidate there; its
                # windows still compete over their whole range, as physics beyond them
                if name in used or (before is not None and name in self.refit
                                    and name not in self.profile_boxes):
                    continue
                box = boxes.get(name) or resolved_box(name, self.shape)
                results.append(self._candidate(name, box, not profile, k + 1))
                if self.progress:
                    self.progress(name)
            best = self._judge(results, k, set(boxes)) if results else None
            if best is None:
                if before is not None:
                    # nothing named: the camera stays as the profile's rounds left it (a
                    # camera freed whole overfits a small sweep, :meth:`try_whole_camera`)
                    self.problem, self.refit = before
                break
            _log.info("round %d: %s (score %.1f, t %.1f)", k + 1, best.effect, best.score,
                      best.t_stat)
            if before is not None:
                # named over the whole camera, modelled beside the profile's takes: the whole
                # camera freed in the model trades offset, wiggle and amplitude bias along
                # their shared valley, and each would then be reported as the camera's
                self.problem, self.refit = before
                best = self._candidate(best.effect, boxes.get(best.effect)
                                       or resolved_box(best.effect, self.shape), True, k + 1)
            used.append(best.effect)
            self.taken.append(best.effect)
            if best.effect in rejoin:
                self.joined.append(best.effect)
                self.refit = [*self.refit, best.effect]
            else:
                taken.append(best.effect)
                if not profile:
                    self.named.append(best.effect)
                    self._name_beyond_window(best.effect)
            self._rebase(best.config)
        return taken

    def _judge(self, results: list[FitResult], k: int,
               boxed: Collection[str]) -> FitResult | None:
        """Round ``k``'s ``results`` ranked and kept with their evidence; the candidate it
        takes (:meth:`_first_explained`), or None."""
        results = rank(results, self.problem)
        self.rounds.append(results)
        for r in results:
            self.evidence[f"{k + 1}:{r.effect}"] = explain(self.problem, r, self.descriptors)
        self._measure_concentration(results, k, boxed=boxed)
        # once physics is named, the residual holds that fit's imperfections too
        threshold = (self.min_score if not self.named
                     else max(self.min_score, MIN_SCORE_LATER))
        return self._first_explained(results, threshold, k, boxed=boxed)

    def _candidate(self, name: str, box: Sequence[tuple[float, float]] | None,
                   released: bool, round_: int) -> FitResult:
        """``name`` fitted on the current model (searched in ``box``) with ``refit`` refitted
        beside it (:meth:`_with_refit`) and scored; ``released``: against the camera's window
        released when it sits at its limit (:meth:`_released`)."""
        current = self.problem
        self.problem = (self._released(name) if released else None) or current
        held = fit_effect(self.problem, name, box=box)
        result = self._with_refit(held, box)
        self.problem = current
        _log.debug("round %d: %s scores %.1f with the camera held, %.1f refitted", round_,
                   name, held.score, result.score)
        return result

    def _camera_refitted(self) -> tuple[Problem, list[str]] | None:
        """One-shot scene rounds: the whole camera (``camera``) refitted on the current model
        without any candidate (:meth:`_descend`) becomes what the round's candidates are
        refitted with and scored against; returns the problem and ``refit`` before, for the
        round to put back when it names nothing. None without a whole camera (monitoring).

        Why: judged over the profile *taken*, a candidate is credited with what the camera
        effects the profile's rounds left out would have explained. A 30 MHz camera's wiggle
        of 5.4 mm scored 7–12 mnats/px alone, below the threshold, and a two-parameter halo
        then took its place at 16.1 on a control; absorbed halos went the other way (session
        39). Over the whole camera refitted, a candidate is credited only with what the camera
        cannot take, as :func:`refitted_margin` measures the truth's effects."""
        if not self.camera:
            return None
        before = (self.problem, self.refit)
        self.refit = list(dict.fromkeys([*self.refit, *self.camera]))
        self._rebase(self._descend(self.problem.base, None, None)[0])
        _log.debug("the whole camera refitted without the candidates gains %.1f mnats per "
                   "training pixel", 1000.0 * (self._train_cost(before[0].base)
                                               - self._train_cost(self.problem.base)))
        return before

    def _released(self, effect: str) -> Problem | None:
        """The current problem with the camera window ``effect`` put back to its value before
        the profile was fitted, when the profile holds it at the window's upper limit; else
        None. A window fitted at its limit says the camera's own share is at least that, not
        that the rest is something else: a lens blur of 1.0 px became the window's 0.6 px
        (15.6 mnats/px) and left a scene blur worth 5.4 over it, below the threshold, though
        the whole blur pays 30 over a camera refitted from the truth (session 39,
        ``profile_s122/1``). Scored against the released window, the candidate is credited
        with all of it."""
        if (effect not in RELEASED_WINDOWS or effect not in self.profile_boxes
                or effect not in self.refit or self.profile_start is None):
            return None
        param, _, high = CAMERA_WINDOWS[effect]
        spec = next(p for p in free_params(effect) if p.name == param)
        value = float(self.problem.base.params(effect)[param])
        if spec.unit(value) < spec.unit(high) - EDGE_FRACTION:
            return None
        start = self.profile_start.params(effect)
        return _rebased(self.problem, self.problem.base.with_effect(effect, **start))

    def _name_beyond_window(self, effect: str) -> None:
        """``effect``, a camera window, named as physics beyond the window: no longer the
        profile's, so no later refit pulls it back inside the window."""
        if effect in self.profile_boxes:
            self.refit = [e for e in self.refit if e != effect]
            self.camera = [e for e in self.camera if e != effect]
            self.profile_boxes = {e: b for e, b in self.profile_boxes.items() if e != effect}

    def _first_explained(self, results: list[FitResult], threshold: float,
                         k: int, boxed: Collection[str] = ()) -> FitResult | None:
        """The best significant candidate whose fit the model explains: one fitted at the edge
        of a parameter's range is evidence that the model does not explain the residual, so it
        is reported (``unexplained``) and never taken on that basis. Nor, in the one-shot
        workflow, is a fit inside the camera's own window (a multipath gain the assumed units
        explain, a focused lens's blur) named as physics; ``boxed`` are the profile's fits of
        those windows, which are taken. Below the significance of the per-pixel score, a
        warm-up drift may still be taken on the held-out frames' levels
        (:meth:`_by_frame_levels`), and an effect that acts on few pixels on the residual where
        its correction is large (:meth:`_by_concentration`)."""
        past_significant = False
        for r in results:
            if past_significant or not _significant(r, threshold, self.min_t):
                # ranked by score, none further is significant by it; but an effect of one
                # offset per frame is also judged on the frames' levels, and a concentrated
                # effect where it acts: there its signature shows
                past_significant = True
                if not (self._by_frame_levels(r, k) or self._by_concentration(r, k)):
                    continue
            if self.units_assumed and r.effect not in boxed and within_camera_window(r):
                param, lo, hi = CAMERA_WINDOWS[r.effect]
                self._unexplain("camera_window", r.effect, k + 1, r.score, param=param,
                                value=r.parameters[param], low=lo, high=hi,
                                **CAMERA_WINDOW_REASONS[r.effect])
                continue
            edge = parameters_at_edge(r)
            chosen = self._away_from_edge(r, edge) if edge else r
            if chosen is None:
                self._unexplain("edge", r.effect, k + 1, r.score, edge)
            elif self._signature_holds(chosen, k, boxed):
                return chosen
        return None

    def _signature_holds(self, r: FitResult, k: int, boxed: Collection[str]) -> bool:
        """Whether ``r``, if an effect of ``SIGNATURE_EFFECTS`` named as physics (not the
        camera's window, ``boxed``), explains the held-out residual where its own correction
        is large (:mod:`.concentration`'s test). A gain of interreflection acts most at
        concave corners and where objects meet the table; one that leaves most of the
        residual there is bending to a misfit elsewhere — glossy or metal parts, which a
        Lambertian model cannot light, want a far larger gain than the diffuse surfaces
        around them — and is reported as ``"signature"``, not named (issue 13, item 2).
        Without ``MIN_GROUPS`` groups there is no evidence of where it acts: it holds."""
        if r.effect not in SIGNATURE_EFFECTS or r.effect in boxed:
            return True
        levels = group_levels(self.problem, r.config)
        if levels is None:
            return True
        found = self.concentration[f"{k + 1}:{r.effect}"] = levels.as_dict()
        if found["groups"] < MIN_GROUPS or found["explained"]:
            return True
        self._unexplain("signature", r.effect, k + 1, r.score, share_left=found["share_left"],
                        groups=found["groups"])
        return False

    def _unexplain(self, case: str, effect: str, round_: int | None, score: float | None,
                   edge: dict[str, float] | None = None, **why: Any) -> None:
        """Add an ``unexplained`` entry of ``case`` (the template's ``unexplained_why`` words,
        given ``why``), with where the residual sits."""
        self.unexplained.append({
            "round": round_, "effect": effect, "case": case,
            "score": None if score is None else round(score, 3),
            "parameters_at_edge": edge or {},
            "why": phrase("unexplained_why", {"case": case, **why}),
            "where": self.location.get("flagged", [])[:3]})

    def _by_frame_levels(self, r: FitResult, k: int) -> bool:
        """Whether ``r`` (an effect of ``FRAME_LEVEL_EFFECTS``) explains how the held-out
        frames' levels move (:mod:`.frame_levels`: their χ² is the significance test here, in
        place of the per-pixel score and tile t) without making the held-out pixels worse
        (a positive score); the levels are kept in ``frame_levels`` as evidence."""
        if r.effect not in FRAME_LEVEL_EFFECTS or r.note:
            return False
        levels = frame_levels(self.problem, r.config)
        if levels is None:
            return False
        self.frame_levels[f"{k + 1}:{r.effect}"] = levels.as_dict()
        return levels.explained and r.score > 0

    def _measure_concentration(self, results: list[FitResult], k: int,
                               boxed: Collection[str]) -> None:
        """Keep, for every concentrated candidate of round ``k`` fitted over its whole range,
        the held-out residual where its correction is large (:mod:`.concentration`)."""
        for r in results:
            if r.effect in CONCENTRATED_EFFECTS and r.effect not in boxed and not r.note:
                levels = group_levels(self.problem, r.config)
                if levels is not None:
                    self.concentration[f"{k + 1}:{r.effect}"] = levels.as_dict()

    def _by_concentration(self, r: FitResult, k: int) -> bool:
        """Whether ``r`` (an effect of ``CONCENTRATED_EFFECTS``) explains the held-out residual
        where its correction is large (:mod:`.concentration`: the groups' χ² is the
        significance test here, in place of the per-pixel score), alone among the round's
        concentrated candidates, without making the held-out pixels worse (a positive
        score). When a halo, a blur and a misregistration all explain it, it is a misfit any
        smooth correction bends to, not one effect's signature (issue 13, item 2)."""
        found = self.concentration.get(f"{k + 1}:{r.effect}")
        if not (found and found["explained"] and r.score > 0):
            return False
        return not any(v["rival"] for key, v in self.concentration.items()
                       if key.startswith(f"{k + 1}:") and key != f"{k + 1}:{r.effect}"
                       and key.split(":", 1)[1] in CONCENTRATED_EFFECTS)

    def confirm(self, profile: list[str], given: ToFConfig) -> list[str]:
        """The effects of ``profile`` significant in the final model: each is put back to its
        ``given`` value and scored as a candidate again; one that does not pay is dropped (and
        stays at its given value). ``profile`` may hold effects the profile's rounds did not
        take, refitted with the whole camera: what pays beside the physics joins it here."""
        kept = []
        for name in profile:
            current = self.problem.base
            without = replace(current, effects={**current.effects,
                                                name: given.effects[name]})
            # judged at the given level: a free level would hide a changed offset; but what was
            # fitted with the level free (the camera's windows) is judged so again
            trial = _rebased(self.problem, without).judged(
                free_level=name in self.profile_boxes)
            back = score_fit(trial, FitResult(name, current, {}, len(free_params(name))))
            if _significant(back, self.min_score, self.min_t):
                kept.append(name)
            else:
                self.problem = trial.judged(free_level=self.problem.free_level)
        return kept

    def flag_profile_edges(self, profile: list[str]) -> None:
        """Report (``unexplained``, case ``"profile_edge"``) every profile effect whose final
        value sits at a limit of its realistic range (:func:`parameters_at_edge`): the refits
        beside the scene candidates may push the profile there, and a camera's own value does
        not sit at a search limit (issue 13, item 2: misspecification is evidence). Measured
        in session 15: in 3 of 6 visible misses a halo or misregistration had been absorbed by
        a wiggle or an amplitude bias at its edge."""
        final = self.problem.base
        for name in profile:
            fitted = FitResult(name, final, plain_params(final, name), len(free_params(name)))
            edge = parameters_at_edge(fitted)
            if edge:
                self._unexplain("profile_edge", name, None, None, edge)

    def measure_pattern(self, profile: list[str]) -> list[str]:
        """One-shot, once the effects are named: the camera's fixed pattern is projected out
        of the final model (:attr:`.fit.Problem.free_pattern`) and the noise law refitted
        beside it, joining the profile when that is significant. No seed of the simulator
        reproduces another camera's pattern; left in the residual, its millimetres pass for
        noise. Why only now: projected out while the effects were named, the pattern estimate
        also took some of what a scene effect leaves near the objects (a halo of 0.08 over 30
        px was lost, the pattern read 5.2 mm for the camera's 3.0), and named nothing that was
        missed without it (docs/mismatch.md, session 15). Returns the profile."""
        self.problem = self.problem.judged(free_pattern=True)
        noise = fit_effect(self.problem, "noise_model")
        if not _significant(noise, self.min_score, self.min_t):
            return profile
        self._rebase(noise.config)
        return profile if "noise_model" in profile else [*profile, "noise_model"]

    def _away_from_edge(self, result: FitResult, edge: dict[str, float]) -> FitResult | None:
        """The same candidate refitted with its edge parameters kept off the edge, if that
        fits (nearly) as well: then the edge was a flat valley of degenerate parameters (a
        drift's size and time constant over a few frames), not a limit the data pushes
        against. None when the edge binds: the model does not explain the residual."""
        box = []
        params = free_params(result.effect)
        searched = resolved_box(result.effect, self.shape) or [(0.0, 1.0)] * len(params)
        for p, (lo, hi) in zip(params, searched, strict=True):
            u = p.unit(result.parameters.get(p.name, p.low))
            inner = ((0.0, 1.0) if p.name not in edge else
                     (0.0, 1.0 - INNER_MARGIN) if u > 0.5 else (INNER_MARGIN, 1.0))
            box.append((max(lo, inner[0]), min(hi, inner[1])))
        q = self._with_refit(fit_effect(self.problem, result.effect, box=box), box)
        if q.note or parameters_at_edge(q) or \
                q.train_gain < EDGE_SLACK * result.train_gain:
            return None
        return q

    def _with_refit(self, result: FitResult,
                    box: Sequence[tuple[float, float]] | None = None) -> FitResult:
        """``result`` with the camera's profile refitted on top of it, scored against the
        current model: what the profile absorbed of this physics before it was tried (a mean
        offset of a warm-up drift, a range-dependent share of interreflection, a wiggle that
        stood in for a lens's halo) goes back to it.

        Descent (:meth:`_sweep`): the profile and the candidate fitted jointly with the noise
        law held, then the noise law, in sweeps until one gains less than ``REFIT_TOL`` per
        training pixel (at most ``REFIT_SWEEPS``). Fitted one at a time, effects that trade the
        same smooth residual creep along their shared valley (a halo's fraction climbed 0.016
        → 0.024 over six sweeps; session 27: a multipath gain stopped at 0.49 of a true 0.13).
        In the one-shot workflow a second descent starts with the profile back at its values
        before it was fitted (:meth:`_restart`); of the two ends, the better held-out score is
        kept."""
        if result.note or not self.refit:
            return result
        ends = [self._descend(result.config, result.effect, box)]
        restarted = self._restart(result.effect, box)
        if restarted is not None:
            ends.append(restarted)
        base_cost = self._train_cost(self.problem.base)
        fits = [result if config is result.config else
                score_fit(self.problem, FitResult(
                    result.effect, config, plain_params(config, result.effect),
                    result.n_params, train_gain=base_cost - cost))
                for config, cost in ends]
        # the held-out pixels choose between the two ends as they choose between candidates:
        # the two fit the training pixels alike when the profile and the candidate trade the
        # same residual (a wiggle of 9 mm and a halo of 0.05, or a wiggle of 5.5 mm and the
        # true halo of 0.10: 1.4 mnats/px apart on training pixels, 8 on held-out ones)
        return max(fits, key=lambda r: r.score)

    def _restart(self, effect: str, box: Sequence[tuple[float, float]] | None
                 ) -> tuple[ToFConfig, float] | None:
        """The candidate's second descent, in the other order: the profile put back to its
        values before it was fitted (``profile_start``), ``effect`` fitted there, then the same
        descent. The profile was fitted before any scene physics, so it has already
        absorbed what it could of it (a halo of 0.086 over 37 px became a −4 mm offset and a
        wiggle, and a descent from there found a halo of 0.007: session 18); started from the
        camera's given values (the nominal cell's, one-shot), the candidate takes its own share
        first. The model reached and its training cost, or None without a start or a fit."""
        if self.profile_start is None:
            return None
        current = self.problem.base
        reset = replace(current, effects={
            **current.effects,
            **{name: self.profile_start.effects[name] for name in self.refit if name != effect}})
        fitted = fit_effect(_rebased(self.problem, reset), effect, box=box)
        if fitted.note:
            return None
        return self._descend(fitted.config, effect, box)

    def _descend(self, config: ToFConfig, effect: str | None,
                 box: Sequence[tuple[float, float]] | None) -> tuple[ToFConfig, float]:
        """Descent from ``config`` (:meth:`_sweep`s while one gains at least ``REFIT_TOL`` per
        training pixel, at most ``REFIT_SWEEPS``): the model reached and its training cost.
        ``effect`` None: the profile alone."""
        cost = self._train_cost(config)
        for _ in range(REFIT_SWEEPS):
            swept = self._sweep(config, effect, box)
            swept_cost = self._train_cost(swept)
            if swept_cost > cost - REFIT_TOL:
                if swept_cost < cost:
                    config, cost = swept, swept_cost
                break
            config, cost = swept, swept_cost
        return config, cost

    def _sweep(self, config: ToFConfig, effect: str | None,
               box: Sequence[tuple[float, float]] | None) -> ToFConfig:
        """One sweep: the profile and ``effect`` (searched in ``box``) fitted jointly with the
        noise law held (:func:`.fit.joint_fit`), then the noise law on that. Returns
        ``config`` itself when nothing improved."""
        jointly = [e for e in dict.fromkeys([*self.refit, *([effect] if effect else [])])
                   if e != "noise_model"]
        boxes = {**self.profile_boxes, **({effect: box} if effect else {})}
        fitted = joint_fit(_rebased(self.problem, config), jointly, boxes)
        if "noise_model" in self.refit or effect == "noise_model":
            q = fit_effect(_rebased(self.problem, fitted), "noise_model",
                           box=box if effect == "noise_model" else None)
            if not q.note and q.train_gain > 0:
                fitted = q.config
        return fitted

    def try_whole_camera(self, whole: Sequence[str]) -> None:
        """One-shot, after the profile's rounds: refit ``whole`` (every profile effect and
        window, taken or not) jointly, and keep it as the profile refitted beside every later
        candidate if that is significant on the held-out pixels over the profile taken (its
        new parameters penalised). Why (session 29): the rounds take a camera effect only when
        it pays by itself, and what they leave at the nominal cell's value can leave a scene
        candidate's residual to a wrong camera (a halo needed the camera's true wiggle and
        window gain beside it, each worth ~20 mnats/px alone; a greedy noise law at two edges
        left 270 mnats/px that a drift could not take). Why judged: freed all at once on a
        small sweep of the nominal cell, they overfit the training pixels (a wiggle at the
        edge of its range balanced by an offset and an amplitude bias)."""
        whole = list(dict.fromkeys([*self.refit, *whole]))
        added = [e for e in whole if e not in self.refit]
        if not added:
            return
        taken = self.refit
        self.refit = whole
        config, cost = self._descend(self.problem.base, None, None)
        trial = score_fit(self.problem, FitResult(
            "camera", config, {}, sum(len(free_params(e)) for e in added),
            train_gain=self._train_cost(self.problem.base) - cost))
        _log.info("the whole camera: score %.1f, t %.1f", trial.score, trial.t_stat)
        if _significant(trial, self.min_score, self.min_t):
            self._rebase(config)
        else:
            self.refit = taken

    def converge_profile(self) -> None:
        """The current model with its profile effects refined jointly (:meth:`_descend`): fitted
        one at a time, they stop short of their joint optimum where they trade the same smooth
        residual, and every later candidate would be scored on what the profile alone still
        gains."""
        if self.refit:
            self._rebase(self._descend(self.problem.base, None, None)[0])

    def _train_cost(self, config: ToFConfig) -> float:
        """Mean cost per training pixel of ``config`` (nats)."""
        total, n = self.problem.total_cost(config, "train")
        return total / max(n, 1)

    def _rebase(self, config: ToFConfig) -> None:
        self.problem = _rebased(self.problem, config)


def _share(masks: Sequence[np.ndarray], frames: Sequence[ToFFrame]) -> float:
    """Share of the frames' measured pixels (finite range) that ``masks`` flag; ``masks``:
    per frame, (H, W) bool on the frame's grid."""
    measured = sum(int(np.isfinite(f.range_mm).sum()) for f in frames)
    flagged = sum(int((m & np.isfinite(f.range_mm)).sum()) for m, f in zip(masks, frames,
                                                                              strict=True))
    return flagged / max(measured, 1)


def _rebased(p: Problem, config: ToFConfig) -> Problem:
    """``p`` around the model ``config``."""
    rebased = [q.rebased(config) for q in p.predictors]
    # a moved camera (pose effects) can leave a pixel unpredicted: judge only pixels that
    # every model so far predicts
    usable = [u & np.isfinite(q.predict().range_mm)
              for u, q in zip(p.usable, rebased, strict=True)]
    return Problem(p.real_mm, rebased, p.split, usable, p.reference_noise_mm, p.edge_jump_mm,
                   free_level=p.free_level, free_pattern=p.free_pattern)


#: the multipath gains the unknown amplitude units explain alone when they were assumed
UNITS_DOUBT = CAMERA_WINDOWS[ALBEDO_EFFECT][1:]


def refitted_margin(frames: Sequence[ToFFrame], config: ToFConfig, effect: str,
                    reference_noise_mm: float = REFERENCE_NOISE_MM
                    ) -> tuple[FitResult, FitResult]:
    """``effect`` scored as the one-shot tool scores a candidate, but from ``config`` (an
    oracle's: the true camera and effects), two ways: (held, fitted). The camera's profile
    (:data:`.profile.PROFILE_EFFECTS`) is descended from ``config`` (:meth:`_Search._descend`,
    the level free) with ``effect`` held at its values there, and fitted jointly with it
    (searched where the tool searches it), each against the profile descended from ``config``
    without ``effect``. A ``score`` (mnats per held-out pixel, after the penalty of
    ``effect``'s parameters, as a candidate's) says whether the data can name ``effect``
    once the camera has taken what it can of it.

    Why: the truth's margin over an answer (:func:`.benchmark.truth_margin`) mixes two
    things: the effect, and the camera the answer ended with. Measured on a hand–eye
    case at 20 MHz (session 39): the truth led the answer by 37 mnats/px, yet from the truth the
    hand–eye error gained 17 mnats/px over the refitted profile, below its 18 of penalty; the
    truth's lead was its camera's (its profile, its exact amplitude units), not the effect's."""
    problem, descriptors = build_problem(frames, config, reference_noise_mm,
                                         specular=specular_masks(frames))
    search = _Search(problem.judged(free_level=True), descriptors, {}, MIN_SCORE, MIN_T,
                     None, refit=list(PROFILE_EFFECTS))
    without, _ = search._descend(config.with_effect(effect, enabled=False), None, None)
    search._rebase(without)
    base_cost = search._train_cost(without)
    # a halo only as wide as the frame resolves, as the tool searches it
    ends = (search._descend(config, None, None),
            search._descend(config, effect, resolved_box(effect, search.shape)))
    held, fitted = (score_fit(search.problem, FitResult(
        effect, end, plain_params(end, effect), len(free_params(effect)),
        train_gain=base_cost - cost)) for end, cost in ends)
    return held, fitted


def within_camera_window(result: FitResult) -> bool:
    """A fit the camera itself could explain (:data:`.profile.CAMERA_WINDOWS`): a multipath
    gain the unknown amplitude units allow (albedo and units are degenerate, and the indirect
    share of the return scales with the senders' albedo), a blur a focused lens gives."""
    if result.effect not in CAMERA_WINDOWS:
        return False
    param, lo, hi = CAMERA_WINDOWS[result.effect]
    return param in result.parameters and lo <= result.parameters[param] <= hi


def window_box(effect: str) -> list[tuple[float, float]]:
    """Unit-box limits of ``effect``'s free parameters: its camera window's parameter within
    the window, the others free."""
    param, lo, hi = CAMERA_WINDOWS[effect]
    return [(p.unit(lo), p.unit(hi)) if p.name == param else (0.0, 1.0)
            for p in free_params(effect)]


#: a halo's width is resolved on a frame up to this share of its short side (issue 13, item 2)
HALO_RESOLVED_SHARE = 0.5
#: the narrowest unit-box interval searched
MIN_BOX_WIDTH = 0.02


def resolved_box(effect: str, shape: tuple[int, int]) -> list[tuple[float, float]] | None:
    """The part of ``effect``'s range a frame of ``shape`` (H, W) resolves, in unit-box
    coordinates, or None for the whole range. A lens halo's glare is told from the global
    light the model lacks (a path tracer's glossy interreflection, ambient light) only by
    how it varies over the frame: wider than ``HALO_RESOLVED_SHARE`` of the short side, its
    kernel's weight varies by less than e^-2 across it and the glare tends to a uniform veil
    of the scene's mean phasor, which any such light adds too. So the width is searched up
    to that: a wider halo is fitted at it, as a halo at least that wide (session 34). On the
    full sensor (240 px) the realistic range (<= 80 px) is searched whole."""
    if effect != "lens_scatter":
        return None
    cap = HALO_RESOLVED_SHARE * float(min(shape))
    box = [(0.0, p.unit(cap)) if p.name == "sigma_px" else (0.0, 1.0)
           for p in free_params(effect)]
    if all(hi >= 1.0 for _, hi in box):
        return None
    # a frame too small for the narrowest halo still gets a sliver to search in
    return [(lo, max(hi, MIN_BOX_WIDTH)) for lo, hi in box]


#: a fitted parameter within this fraction of its range from an edge sits at the edge
EDGE_FRACTION = 0.02
#: camera windows released for the same effect's scene candidate when the profile holds them
#: at their upper limit (:meth:`_Search._released`): a lens's blur, whose window is an optical
#: limit. Not the interreflection's, whose window is the doubt of the grey world's units:
#: there the limit is where the predictor's transport falls short of a path tracer's (4 of 8
#: path-traced blind cases of session 39 held it), which is not more physics of the scene
RELEASED_WINDOWS = ("mixed_pixels",)
#: an edge fit is retried with the edge parameters kept this far (fraction of the range)
#: inside; when that keeps this share of the training gain, the edge did not bind
INNER_MARGIN = 0.1
EDGE_SLACK = 0.97


def parameters_at_edge(result: FitResult) -> dict[str, float]:
    """Fitted parameters of ``result`` at an edge of their realistic range that is only where
    the search stopped: either edge of a signed quantity (±10 mrad of hand-eye rotation, ±20 mm
    of drift) and the upper edge of a magnitude. The lower edge of a magnitude is a physical
    limit (no multipath, the shortest warm-up) that a camera may well sit at."""
    out = {}
    for p in free_params(result.effect):
        if p.name not in result.parameters:
            continue
        if p.periodic:
            continue
        u = p.unit(result.parameters[p.name])
        signed = p.low < 0.0 < p.high
        if u >= 1.0 - EDGE_FRACTION or (signed and u <= EDGE_FRACTION):
            out[p.name] = result.parameters[p.name]
    return out


def _residuals(problem: Problem, config: ToFConfig | None,
               frames: Sequence[int] | None = None) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Per frame (all, or ``frames``): residual and σ on the usable pixels (NaN elsewhere)."""
    idx = range(len(problem.real_mm)) if frames is None else frames
    res, sig = [], []
    for i in idx:
        pred = problem.predictors[i].predict(config)
        r = np.where(problem.usable[i], problem.residual(i, config), np.nan)
        res.append(r)
        sig.append(total_sigma(pred.noise_mm, problem.reference_noise_mm))
    return res, sig


def _finish(problem: Problem, base: ToFConfig, selected: list[str],
            rounds: list[list[FitResult]], evidence: dict[str, str], location: dict[str, Any],
            original: list[FramePredictor],
            descriptors: Sequence[dict[str, np.ndarray]]) -> Analysis:
    after = problem.base
    test = problem.frames_of("test")
    masks = problem.masks("test")
    before_p = Problem(problem.real_mm, original, problem.split, problem.usable,
                       problem.reference_noise_mm, problem.edge_jump_mm)
    rb, sb = _residuals(before_p, None, test)
    ra, sa = _residuals(problem, None, test)
    rb = [np.where(masks[i], r, np.nan) for i, r in zip(test, rb, strict=True)]
    ra = [np.where(masks[i], r, np.nan) for i, r in zip(test, ra, strict=True)]
    metrics = {**residual_metrics(rb, sb, "before"), **residual_metrics(ra, sa, "after")}
    inner = [descriptors[i]["edge_distance_px"] >= INTERIOR_EDGE_PX for i in test]
    for tag, res, sig in (("before", rb, sb), ("after", ra, sa)):
        cut = [np.where(m, r, np.nan) for m, r in zip(inner, res, strict=True)]
        metrics.update({f"interior_{k}": v for k, v in residual_metrics(cut, sig, tag).items()})
    return Analysis(selected, rounds, evidence, base, after, metrics, location, test,
                    rb, ra, sb, sa)


def residual_metrics(residual: Sequence[np.ndarray], sigma: Sequence[np.ndarray],
                     tag: str) -> dict[str, float]:
    """RMSE, MAE, excess RMSE (beyond the noise model) and pixel count of residuals (mm)."""
    r = np.concatenate([x.ravel() for x in residual])
    s = np.concatenate([x.ravel() for x in sigma])
    ok = np.isfinite(r) & np.isfinite(s)
    if not ok.any():
        return {f"rmse_{tag}_mm": float("nan"), f"mae_{tag}_mm": float("nan"),
                f"excess_rmse_{tag}_mm": float("nan"), f"pixels_{tag}": 0}
    r, s = r[ok], s[ok]
    mse = float(np.mean(r ** 2))
    return {f"rmse_{tag}_mm": float(np.sqrt(mse)), f"mae_{tag}_mm": float(np.mean(np.abs(r))),
            f"median_abs_{tag}_mm": float(np.median(np.abs(r))),
            f"excess_rmse_{tag}_mm": float(np.sqrt(max(mse - float(np.mean(s ** 2)), 0.0))),
            f"pixels_{tag}": int(r.size)}


def explain(problem: Problem, result: FitResult,
            descriptors: Sequence[dict[str, np.ndarray]]) -> str:
    """Evidence in words (``templates/mismatch.txt``, ``evidence``): what the fitted effect
    corrects, where, and how well it matches; a candidate that could not be fitted gives its
    note."""
    if result.note:
        return result.note
    return phrase("evidence", evidence_facts(problem, result, descriptors))


def evidence_facts(problem: Problem, result: FitResult,
                   descriptors: Sequence[dict[str, np.ndarray]]) -> dict[str, Any]:
    """What a fitted candidate's evidence says, measured on the held-out pixels.

    Returns:
        ``too_few`` (True when fewer than 10 held-out pixels: nothing else then); else
        ``parameters`` (the fit's), ``test_gain_mnats`` (held-out gain, millinats per pixel),
        ``t`` (tile t-statistic), ``correction`` (None when the fit changes no prediction, else
        ``correlation`` of the correction with the residual clipped at 6σ, its ``rms_mm`` and
        ``where`` it is largest, :func:`_concentration`) and ``variance_ratio`` (mean z² of
        the residual under the nominal noise model; None unless the effect is the noise model
        or the ratio is more than 0.5 from 1).
    """
    test = problem.frames_of("test")
    masks = problem.masks("test")
    res, sig, corr, desc = [], [], [], {n: [] for n in DESCRIPTORS}
    for i in test:
        before = problem.predictors[i].predict()
        after = problem.model_range(i, result.config)
        m = masks[i] & np.isfinite(after)
        res.append(problem.residual(i, None)[m])
        sig.append(total_sigma(before.noise_mm, problem.reference_noise_mm)[m])
        corr.append((after - problem.model_range(i, None))[m])
        for n in DESCRIPTORS:
            desc[n].append(descriptors[i][n][m])
    if not res or sum(x.size for x in res) < 10:
        return {"too_few": True}
    r, s, c = (np.concatenate(x) for x in (res, sig, corr))
    flat = {n: np.concatenate(v) for n, v in desc.items()}
    facts: dict[str, Any] = {"too_few": False, "parameters": dict(result.parameters),
                             "test_gain_mnats": 1000 * result.test_gain, "t": result.t_stat,
                             "correction": None, "variance_ratio": None}
    rc = np.clip(r, -6 * s, 6 * s)
    if np.ptp(c) > 1e-6:
        facts["correction"] = {"correlation": float(np.corrcoef(c, rc)[0, 1]),
                               "rms_mm": np.sqrt(np.mean(c ** 2)),
                               "where": _concentration(flat, c)}
    z2 = float(np.mean((rc / s) ** 2))
    if result.effect == "noise_model" or abs(z2 - 1.0) > 0.5:
        facts["variance_ratio"] = z2
    return facts


def _concentration(flat: dict[str, np.ndarray], correction: np.ndarray) -> dict[str, Any] | None:
    """Where the correction is largest: the descriptor |correction| follows most closely
    (``descriptor``, Spearman ``rho``), its bin of largest mean |correction| (``stratum``,
    :func:`.locate.stratum_facts`) with that mean (``mean_mm``) and the overall one
    (``overall_mm``). None when no descriptor follows it (|rho| < 0.2): spread evenly."""
    mag = np.abs(correction)
    best, best_rho = None, 0.0
    for name, values in flat.items():
        ok = np.isfinite(values)
        if ok.sum() < 10 or np.ptp(values[ok]) == 0:
            continue
        rho = float(np.nan_to_num(stats.spearmanr(values[ok], mag[ok]).statistic))
        if abs(rho) > abs(best_rho):
            best, best_rho = name, rho
    if best is None or abs(best_rho) < 0.2:
        return None
    ok = np.isfinite(flat[best])
    # huge σ: no clipping, only the bins' means are used here
    st = strata(best, flat[best][ok], mag[ok], np.full(int(ok.sum()), 1e12))
    top = max(st, key=lambda x: x.mean_mm)
    return {"stratum": stratum_facts(top.as_dict()), "mean_mm": top.mean_mm,
            "overall_mm": mag.mean(), "rho": best_rho, "descriptor": best}
