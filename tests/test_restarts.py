"""Fresh starts by a rule (``Restarts``): the estimator trains another start when the first
reconstructs poorly, keeps the best, and refuses the rule where it cannot apply."""

from __future__ import annotations

import numpy as np
import pytest

from latent_sindy import LatentSINDy, Phase, Restarts, SequenceData
from latent_sindy.errors import UserError

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def moving_dot(n: int = 12, steps: int = 6) -> SequenceData:
    rng = np.random.default_rng(0)
    pos = rng.uniform(1, 6, (n, 1, 2)) + np.cumsum(rng.uniform(-0.5, 0.5, (n, steps + 1, 2)), 1)
    g = np.arange(8)
    img = np.exp(-((g[None, None, :, None] - pos[..., :1, None]) ** 2
                   + (g[None, None, None, :] - pos[..., 1:, None]) ** 2) / 2.0)
    actions = np.diff(pos, axis=1).astype(np.float32)
    return SequenceData(img[:, :, None].astype(np.float32), actions, seed=0,
                        action_low=[-0.5, -0.5], action_high=[0.5, 0.5])


def fitted(restarts: Restarts, phases=()) -> LatentSINDy:
    est = LatentSINDy(2, encoder="mlp", decoder="mlp", seed=3)
    return est.fit(moving_dot(), epochs=3, starts=1, restarts=restarts, phases=phases)


def test_a_poor_start_is_followed_by_another_and_the_best_is_kept() -> None:
    never = fitted(Restarts(count=1, recon_above=float("inf")))
    always = fitted(Restarts(count=1, recon_above=0.0))
    assert never.kept_["restarts"] == {"starts": 1, "kept": 0}
    assert always.kept_["restarts"]["starts"] == 2
    # the first start is the run without restarts: the same model when it is kept
    plain = LatentSINDy(2, encoder="mlp", decoder="mlp", seed=3).fit(moving_dot(), epochs=3,
                                                                      starts=1)
    assert np.array_equal(plain.coefficients(), never.coefficients())


def test_the_fvu_rule_trains_phases_on_each_start_and_keeps_the_smallest() -> None:
    calib = [Phase(2, "calibration", {"lr": 1e-4})]
    est = fitted(Restarts(count=2, recon_above=float("inf"), fvu_above=0.0), calib)
    assert est.kept_["restarts"]["starts"] == 3  # no start explains everything
    assert est.kept_["phase"] == "calibration"
    assert max(r["epoch"] for r in est.metrics_) == 5  # the kept start's 3 + 2 epochs


def test_the_rule_is_checked_and_refused_for_run_folders(tmp_path) -> None:
    with pytest.raises(UserError, match="count"):
        Restarts(count=-1)
    with pytest.raises(UserError, match="recon_above"):
        Restarts(recon_above=-1.0)
    with pytest.raises(UserError, match="in memory"):
        LatentSINDy(2, encoder="mlp", decoder="mlp").fit(moving_dot(), epochs=1,
                                                         out=tmp_path / "run",
                                                         restarts=Restarts())
    with pytest.raises(UserError, match="Restarts"):
        LatentSINDy(2, encoder="mlp", decoder="mlp").fit(moving_dot(), epochs=1, restarts=3)


def test_without_validation_nothing_is_judged_and_a_warm_up_needs_epochs_left() -> None:
    data = moving_dot()
    no_val = SequenceData(data.images, data.actions, [-0.5, -0.5], [0.5, 0.5], seed=0,
                          split=np.zeros(data.n, np.uint8))
    est = LatentSINDy(2, encoder="mlp", decoder="mlp", seed=3)
    est.fit(no_val, epochs=2, starts=1, restarts=Restarts(count=1, recon_above=0.0))
    assert est.kept_["restarts"] == {"starts": 1, "kept": 0}
    with pytest.raises(UserError, match="warm-up of 2 epochs leaves none"):
        est.fit(data, epochs=2, starts=1, warmup=[Phase(2, "warm-up")])


def test_starts_are_trained_until_two_write_the_same_law() -> None:
    rule = Restarts(count=2, recon_above=float("inf"), agree=2)
    est = fitted(rule)
    starts = est.kept_["restarts"]
    laws = [tuple(map(tuple, s["law"])) for s in starts["laws"]]
    assert starts["starts"] == len(laws) >= 2
    if starts["agreed"]:  # stopped at the first law seen twice; the kept start wrote it
        assert laws[-1] in laws[:-1]
        assert laws[starts["kept"]] == laws[-1]
    else:  # three starts, no two alike
        assert len(set(laws)) == 3


def test_a_law_of_no_term_agrees_with_nothing_and_agree_must_be_whole() -> None:
    from latent_sindy.models.dynamics import ContinuousSindyConfig  # noqa: F401
    from latent_sindy.training.session import law_key

    class Empty:
        sparse = True

        def n_active(self) -> int:
            return 0

    assert law_key(Empty()) == ()
    with pytest.raises(UserError, match="agree"):
        Restarts(agree=0)
    with pytest.raises(UserError, match="agree"):
        Restarts(agree=True)
