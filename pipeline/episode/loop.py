"""One active-mapping episode, Algorithm 1 (PROTOCOL 3, supplement Alg. S1).

Each step: train a fresh model on every view observed so far (the method's stages), evaluate it,
score candidate poses and select the next view, render that view and add it. A step's row is
written atomically once the step is complete, so a killed run resumes at its first missing step
and, with the same seed, selects the same poses (every draw is seeded from (seed, step, purpose)).
"""

import copy
import dataclasses
import math
import time
from collections.abc import Callable

import numpy as np
import torch
from scipy import stats

from nvf.cameras import Intrinsics, matrix_to_pose, pose_to_matrix
from nvf.model import SceneModel
from nvf.observations import Observations
from nvf.planning import Selection, argmax_first, prepare_scorer, score_poses, select_next_view
from nvf.seeding import GeneratorFactory, generator_factory, seeded_generator
from nvf.training import TrainStats, train_model
from nvf.uncertainty import StepScorer
from nvf.visibility_source import SourcedVisibility, label_visibility
from pipeline.episode.evaluation import Evaluator, candidate_score_map
from pipeline.episode.settings import EpisodeSettings
from pipeline.metrics.image import LpipsMetric
from pipeline.records.schema import (
    CandidateScores,
    Metrics,
    OptScores,
    RankAgreement,
    StageSummary,
    StepRow,
    StepSeconds,
)
from pipeline.scenes.ground_truth import open_renderer
from pipeline.scenes.scene import Scene

# (stage, iteration, total, loss) -> None: drives the inner progress bar
TrainProgress = Callable[[str, int, int, float], None]


class Episode:
    """The state of one episode: the scene, its ground-truth renderer (one per episode: for
    ``render.backend=blender`` one Blender process; ``close`` ends it), the observed views and the evaluator.
    It reads its settings (``EpisodeSettings``) alone."""

    def __init__(self, settings: EpisodeSettings, scene: Scene, device: torch.device, lpips: LpipsMetric):
        self.scene = scene
        self.device = device
        self.settings = s = settings
        self.intrinsics = Intrinsics.from_fov(s.budget.image_size, s.budget.image_size)
        self.plan_intrinsics = Intrinsics.from_fov(s.planner.resolution, s.planner.resolution)
        self.method = s.method
        self.scorer = s.scorer()
        self.rival = None if s.rival is None else (s.rival[0], s.rival[1].scorer())
        # last: a Blender renderer is a process, closed by close()
        self.renderer = open_renderer(scene, s.render, s.blender_python)
        self.poses: list[torch.Tensor] = []
        self.images: list[np.ndarray] = []  # RGBA [H, W, 4] training images, budget.gt_samples^2 per pixel
        self.face_ids: list[np.ndarray] = []  # [H, W] face hit by each pixel-centre ray, for Vis. (PROTOCOL 4.3)
        try:
            self.evaluator = Evaluator(scene, self.renderer, s.budget, s.metrics, s.seed, device, lpips)
            for c2w in scene.init_poses:
                self.observe(c2w)
        except BaseException:
            self.close()
            raise
        self.previous_model: SceneModel | None = None

    def close(self) -> None:
        """Release the ground-truth renderer (for Blender, end its process)."""
        self.renderer.close()

    def as_method(self, settings: EpisodeSettings) -> "Episode":
        """This episode under another method's ``settings`` of the same scene, budget and seed: its renderer,
        observations and evaluator shared (not copied; only this episode closes them), its method and scorer the
        other's. What a contender trains and scores at this episode's state."""
        other = copy.copy(self)
        other.settings, other.method, other.scorer, other.rival = settings, settings.method, settings.scorer(), None
        return other

    def observe(self, c2w: torch.Tensor) -> None:
        """Render the ground truth at ``c2w`` and add it to the observations."""
        c2w = c2w.to(torch.float32).cpu()
        self.poses.append(c2w)
        self.images.append(self.renderer.render_rgba(c2w, self.intrinsics, self.settings.budget.gt_samples))
        self.face_ids.append(self.renderer.face_ids(c2w.numpy(), self.intrinsics))

    def observations(self) -> Observations:
        images = torch.from_numpy(np.stack(self.images))
        return Observations(images.to(self.device), torch.stack(self.poses).to(self.device), self.intrinsics)

    def new_model(self, step: int, num_images: int | None = None) -> SceneModel:
        """A freshly initialised model, seeded from (seed, step) (METHOD 10: retrained from scratch), for the
        views observed so far (or ``num_images`` views)."""
        s = self.settings
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(int(seeded_generator(s.seed, step, "init").initial_seed()))
            views = len(self.poses) if num_images is None else num_images
            model = SceneModel(self.scene.object_aabb, s.field, s.sampler, num_images=views)
        model = model.to(self.device)
        if s.train.warm_start and self.previous_model is not None:
            # Deviation (documented in conf): reuse the previous step's weights instead of retraining.
            state = {k: v for k, v in self.previous_model.state_dict().items() if "appearance" not in k}
            model.load_state_dict(state, strict=False)
        return model

    def train(
        self, obs: Observations, step: int, progress: TrainProgress | None = None
    ) -> tuple[SceneModel, TrainStats]:
        """A fresh model (``new_model``) trained on ``obs`` with the method's stages, as step ``step`` trains it."""
        s = self.settings
        model = self.new_model(step)
        generator = seeded_generator(s.seed, step, "train", self.device)
        aux_loss = type(s.method).aux_loss  # read from the class: mypy binds a ClassVar callable read from an instance
        stats = train_model(model, obs, s.train, s.stages, s.entropy, generator, aux_loss, progress)
        return model, stats

    def step(self, step: int, progress: TrainProgress | None = None) -> tuple[StepRow, dict]:
        """Run step ``step``; returns its row (``as_json`` is the line steps.jsonl records) and the images to save
        (name -> HxWx{1,3} array)."""
        s = self.settings
        obs = self.observations()
        t0 = time.perf_counter()
        model, stats = self.train(obs, step, progress)
        t1 = time.perf_counter()
        planning = self.planning_model(model, obs)
        psnr_only = s.step_metrics == "psnr" and step < s.budget.horizon - 1
        metrics, images, _ = self.evaluator.evaluate(
            planning, self.scorer, self.face_ids, obs, step, psnr_only=psnr_only
        )
        t2 = time.perf_counter()
        selection, generators = self.plan(planning, obs, step)
        t3 = time.perf_counter()
        if "score" in images and selection.scores is not None and isinstance(self.scorer, StepScorer):
            images["score"] = candidate_score_map(  # whole-view scores: no per-pixel map, the candidates from above
                selection.candidates[:, 4:].cpu().numpy(),  # type: ignore[index]  # set with its scores
                selection.scores.cpu().numpy(),
                self.scene.camera_box.numpy(),
                images["score"].shape[0],
            )
        self.previous_model = model if s.train.warm_start else None
        scores = selection.candidate_scores
        row = StepRow(
            step=step,
            n_views=len(self.poses),
            status="ok",
            metrics=Metrics(**metrics),
            selected_pose=selection.pose.detach().cpu().tolist(),
            selected_index=selection.index,
            selected_score=selection.score,
            refined=selection.refined,
            candidate_scores=CandidateScores(**dataclasses.asdict(scores))
            if scores
            else CandidateScores(selection.num_candidates, None, None, None, None, None),
            train={stage: StageSummary(**summary) for stage, summary in stats.stages.items()},
            seconds=StepSeconds(train=t1 - t0, eval=t2 - t1, plan=t3 - t2),
            opt=None
            if selection.opt is None
            else OptScores(selection.opt.original_scores.tolist(), selection.opt.refined_scores.tolist()),
            rank_agreement=self.rank_agreement(planning, selection, obs, generators)
            if self.rival is not None and selection.scores is not None
            else None,
        )
        return row, images

    def plan(
        self, planning: SceneModel | SourcedVisibility, obs: Observations, step: int
    ) -> tuple[Selection, GeneratorFactory]:
        """Step ``step``'s next view from the model the scores read (``planning_model``): the method's scorer
        (prepared on ``obs`` if it scores whole views) over the candidates from the last observed pose
        (METHOD 12-14); also the step's generators."""
        s = self.settings
        current = matrix_to_pose(self.poses[-1]).to(self.device)
        generators = generator_factory(s.seed, step, self.device)
        scorer = prepare_scorer(self.scorer, planning, obs, generators, s.planner.score_chunk_rays)
        selection = select_next_view(
            planning,
            scorer,
            s.planner,
            self.scene.camera_box.to(self.device),
            current,
            self.plan_intrinsics,
            s.tau,
            s.collision_free,
            generators,
            self.renderer.unoccluded,
        )
        return selection, generators

    def planning_model(self, model: SceneModel, obs: Observations) -> SceneModel | SourcedVisibility:
        """The model the scores read (``nvf.entropy.visibility_source``): ``model`` itself (its visibility
        head), or ``model`` with ``v`` from M17-M18 labels at the scored samples or from the scene mesh's
        line of sight to the training cameras (an oracle; ``train.label_margin`` applies to both)."""
        s = self.settings
        source = s.entropy.visibility_source
        if source == "head":
            return model
        if source == "labels":
            return SourcedVisibility(model, label_visibility(model, obs.c2w, obs.intrinsics, s.train))
        c2w, margin = obs.c2w, s.train.label_margin

        def mesh_visibility(points: torch.Tensor) -> torch.Tensor:
            seen = self.renderer.line_of_sight(points, c2w, obs.intrinsics, margin)
            return seen.to(device=points.device, dtype=points.dtype)

        return SourcedVisibility(model, mesh_visibility)

    def rank_agreement(
        self,
        model: SceneModel | SourcedVisibility,
        selection: Selection,
        obs: Observations,
        generators: GeneratorFactory,
    ) -> RankAgreement:
        """How the ``diagnostics.rank_against`` ablation's score ranks the step's candidates against the run's
        own: Spearman correlation and whether both pick the same candidate (no randomness: the run's
        choices are unchanged)."""
        assert self.rival is not None, "ranked only for a run with diagnostics.rank_against"
        name, rival_scorer = self.rival
        chunk = self.settings.planner.score_chunk_rays
        scorer = prepare_scorer(rival_scorer, model, obs, generators, chunk)
        candidates, scores = selection.candidates, selection.scores
        assert scorer is not None and candidates is not None and scores is not None, "ranked only for a scoring method"
        rival = score_poses(model, scorer, candidates, self.plan_intrinsics, chunk)
        own = scores.detach().cpu().numpy()
        spearman = float(stats.spearmanr(own, rival.detach().cpu().numpy()).statistic) if len(own) > 1 else math.nan
        same = argmax_first(rival) == argmax_first(scores)
        return RankAgreement(against=name, spearman=spearman, same_choice=same)

    def observe_pose(self, pose: list[float]) -> None:
        """Observe a pose vector ``[qx, qy, qz, qw, x, y, z]`` (a selected view)."""
        self.observe(pose_to_matrix(torch.tensor(pose, dtype=torch.float32)))

    def replay(self, rows: list[dict]) -> None:
        """Re-observe the poses selected by completed steps (resume)."""
        for row in rows:
            self.observe_pose(row["selected_pose"])
