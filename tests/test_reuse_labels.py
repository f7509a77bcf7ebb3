"""Labels from earlier runs: a run starts from the answers of earlier journals, read and checked as the run reads its own."""

import json
import os

import gymnasium as gym
import numpy as np
import pytest

from sb3_pride import PEBBLE
from sb3_pride.common.journal import JournalEntry, PreferenceJournal, query_id
from sb3_pride.common.priors import read_prior_preferences


@pytest.fixture(scope="module")
def earlier_journal(tmp_path_factory):
    """The journal of a finished tiny PEBBLE run on Pendulum (seed 0, 60 answers)."""
    from conftest import TINY

    path = tmp_path_factory.mktemp("earlier") / "preferences.jsonl"
    PEBBLE("MlpPolicy", "Pendulum-v1", seed=0, preference_journal=path, **TINY).learn(1000)
    return path


def test_a_journal_starts_with_what_its_pairs_are_about(earlier_journal):
    header = PreferenceJournal(earlier_journal).header()
    assert header == {"env_id": "Pendulum-v1", "observation_shape": [3], "action_shape": [1], "segment_length": 10}
    assert len(PreferenceJournal(earlier_journal).read()) == 60


def test_priors_train_r_hat_from_the_first_session_count_nowhere_and_are_never_asked_again(
    earlier_journal, tiny_kwargs, tmp_path
):
    own = tmp_path / "own.jsonl"
    model = PEBBLE(
        "MlpPolicy", "Pendulum-v1", seed=0, preference_journal=own, prior_preferences=[earlier_journal], **tiny_kwargs
    )
    assert len(model.preferences) == 60 and model.phase.asked == 0
    model.learn(1000)
    history = model.reward_learner.history
    # r̂ learned from the 60 priors at the first session, and from the run's own labels beside them from then on
    assert history[0]["session"] == 1 and history[0]["labels"] >= 60
    assert history[-1]["labels"] == 60 + model.phase.labeled > 60
    assert model.phase.labeled == len(model.preferences) - 60 and model.phase.asked <= tiny_kwargs["max_feedback"]
    # the same seed draws the earlier run's first queries again: none of them is asked
    earlier_ids = {entry.id for entry in PreferenceJournal(earlier_journal).read()}
    own_ids = {entry.id for entry in PreferenceJournal(own).read()}
    assert own_ids and not own_ids & earlier_ids
    header = PreferenceJournal(own).header()
    assert header is not None and header["prior_preferences"][0]["path"] == str(earlier_journal)
    assert header["prior_preferences"][0]["labels"] == 60 and len(header["prior_preferences"][0]["sha1"]) == 40


def test_without_priors_the_same_seed_asks_the_earlier_runs_queries(earlier_journal, tiny_kwargs, tmp_path):
    """The deliberately bad case of the test above: with no priors, the first session repeats the earlier run's."""
    own = tmp_path / "own.jsonl"
    PEBBLE("MlpPolicy", "Pendulum-v1", seed=0, preference_journal=own, **dict(tiny_kwargs, max_feedback=20)).learn(400)
    earlier_ids = {entry.id for entry in PreferenceJournal(earlier_journal).read()}
    assert {entry.id for entry in PreferenceJournal(own).read()} & earlier_ids


def test_a_saved_run_keeps_its_priors_and_their_origin(earlier_journal, tiny_kwargs, tmp_path):
    model = PEBBLE("MlpPolicy", "Pendulum-v1", seed=1, prior_preferences=[earlier_journal], **tiny_kwargs)
    model.save(tmp_path / "model.zip")
    loaded = PEBBLE.load(tmp_path / "model.zip", env=gym.make("Pendulum-v1"))
    assert len(loaded.preferences) == 60
    assert loaded.feedback.journal.asked_ids() >= {entry.id for entry in PreferenceJournal(earlier_journal).read()}


def test_skips_undos_and_several_annotators_are_read_as_the_run_read_them(tmp_path):
    journal = PreferenceJournal(tmp_path / "team.jsonl")
    rng = np.random.default_rng(0)
    pairs = [rng.normal(size=(2, 5, 4)).astype(np.float32) for _ in range(4)]
    journal.append([JournalEntry(1, pairs[0], 1.0, "ann"), JournalEntry(1, pairs[0], 0.0, "bob")])  # mean 0.5
    journal.append([JournalEntry(1, pairs[1], float("nan"))])  # a skip: asked, not learned from
    journal.append([JournalEntry(1, pairs[2], 1.0)])
    journal.append_undo(1)  # takes pairs[2]'s answer back
    journal.append([JournalEntry(2, pairs[3], 0.0)])
    header = {"env_id": None, "observation_shape": [3], "action_shape": [1], "segment_length": 5}
    priors = read_prior_preferences([journal.path], header, (2, 5, 4))
    assert priors.labels.tolist() == [0.5, 0.0]
    np.testing.assert_array_equal(priors.inputs[1], pairs[3])
    assert len(priors.ids) == 3  # the skip is never asked again either
    assert priors.sources[0]["labels"] == 2


def test_a_journal_of_another_env_or_cut_short_is_refused_and_nothing_is_recorded(earlier_journal, tiny_kwargs, tmp_path):
    own = tmp_path / "own.jsonl"
    with pytest.raises(ValueError, match=r"preferences.jsonl is about other pairs: its env id 'Pendulum-v1'.*observation"):
        PEBBLE("MlpPolicy", "MountainCarContinuous-v0", preference_journal=own, prior_preferences=[earlier_journal],
               **tiny_kwargs)  # fmt: skip
    torn = tmp_path / "torn.jsonl"
    torn.write_text(earlier_journal.read_text()[:-40])
    with pytest.raises(ValueError, match=r"torn.jsonl: line 61 is not JSON \(a last line cut"):
        PEBBLE("MlpPolicy", "Pendulum-v1", preference_journal=own, prior_preferences=[torn], **tiny_kwargs)
    other_segments = dict(tiny_kwargs, segment_length=20)
    with pytest.raises(ValueError, match=r"its segment_length 10 \(this run: 20\)"):
        PEBBLE("MlpPolicy", "Pendulum-v1", preference_journal=own, prior_preferences=[earlier_journal], **other_segments)
    with pytest.raises(ValueError, match=r"missing.jsonl is not a file"):
        PEBBLE("MlpPolicy", "Pendulum-v1", preference_journal=own, prior_preferences=[tmp_path / "missing.jsonl"],
               **tiny_kwargs)  # fmt: skip
    with pytest.raises(ValueError, match=r"prior_preferences must be a list of journal paths"):
        PEBBLE("MlpPolicy", "Pendulum-v1", preference_journal=own, prior_preferences=str(earlier_journal), **tiny_kwargs)
    assert not own.exists()


def test_a_journal_without_a_header_is_checked_on_its_pairs(earlier_journal, tiny_kwargs, tmp_path):
    bare = tmp_path / "bare.jsonl"
    lines = earlier_journal.read_text().splitlines(keepends=True)
    assert "journal" in json.loads(lines[0])
    bare.write_text("".join(lines[1:]))
    model = PEBBLE("MlpPolicy", "Pendulum-v1", prior_preferences=[bare], **tiny_kwargs)
    assert len(model.preferences) == 60
    with pytest.raises(ValueError, match=r"holds pairs of shape \(2, 10, 4\), this run's are \(2, 10, 3\)"):
        PEBBLE("MlpPolicy", "MountainCarContinuous-v0", prior_preferences=[bare], **tiny_kwargs)


def test_a_query_in_several_priors_is_one_preference_and_the_runs_own_journal_is_no_prior(
    earlier_journal, tiny_kwargs, tmp_path
):
    twice = PEBBLE("MlpPolicy", "Pendulum-v1", prior_preferences=[earlier_journal, earlier_journal], **tiny_kwargs)
    assert len(twice.preferences) == 60
    with pytest.raises(ValueError, match=r"preferences.jsonl is this run's own preference_journal"):
        PEBBLE("MlpPolicy", "Pendulum-v1", preference_journal=earlier_journal, prior_preferences=[earlier_journal],
               **tiny_kwargs)  # fmt: skip


def test_a_journal_book_saved_without_a_header_loads_with_none(tmp_path):
    import pickle

    from sb3_pride.common.journal import JournalBook

    book = JournalBook(tmp_path / "j.jsonl", (2, 5, 4))
    del book.header, book.prior_ids  # as a book pickled before it had them
    loaded = pickle.loads(pickle.dumps(book))
    assert loaded.header is None and loaded.prior_ids == set()


def test_the_header_is_written_with_the_first_answers_and_a_torn_header_is_cut(tmp_path):
    from sb3_pride.common.journal import JournalBook

    path = tmp_path / "j.jsonl"
    path.write_text('{"journal": {"env_id": "Pend')  # a crash in the middle of the first write
    book = JournalBook(path, (2, 5, 4), header={"env_id": "Pendulum-v1", "segment_length": 5})
    book.record([JournalEntry(1, np.zeros((2, 5, 4), dtype=np.float32), 1.0)])
    lines = path.read_text().splitlines()
    assert json.loads(lines[0]) == {"journal": {"env_id": "Pendulum-v1", "segment_length": 5}} and len(lines) == 2


def test_a_session_whose_candidates_were_all_answered_before_draws_fresh_ones(earlier_journal, tiny_kwargs, tmp_path):
    """The same seed draws the earlier run's first queries again: the session asks fresh ones, the budget in full."""
    import warnings

    settings = dict(tiny_kwargs, max_feedback=40, queries_per_session=20)  # sessions at steps 300 and 600
    model = PEBBLE("MlpPolicy", "Pendulum-v1", seed=0, preference_journal=tmp_path / "own.jsonl",
                   prior_preferences=[earlier_journal], **settings)  # fmt: skip
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no budget warning, no short session
        model.learn(700)
    assert model.phase.sessions == 2 and model.phase.asked == 40
    own = PreferenceJournal(tmp_path / "own.jsonl").read()
    assert [entry.session for entry in own] == [1] * 20 + [2] * 20
    earlier_ids = {entry.id for entry in PreferenceJournal(earlier_journal).read()}
    assert not {entry.id for entry in own} & earlier_ids and len({entry.id for entry in own}) == 40


def test_a_session_that_finds_too_few_pairs_never_asked_says_how_many_it_could_not_ask(tiny_kwargs):
    """Episodes of one segment, queries from two finished ones: 4 distinct pairs exist, a session of 20 asks those 4."""
    env = gym.make("Pendulum-v1", max_episode_steps=10)
    # the third of the recent episodes is the running one, a step short of a segment when the session opens
    settings = dict(tiny_kwargs, queries_per_session=20, max_feedback=20, query_kwargs=dict(max_query_episodes=3))
    model = PEBBLE("MlpPolicy", env, seed=0, **settings)
    with pytest.warns(UserWarning, match=r"feedback session 1 asks 4 of its 20 queries: .*16 .*not asked"):
        model.learn(310)
    assert model.phase.asked == 4
    assert len({query_id(pair) for pair in model.preferences.inputs}) == len(model.preferences)


@pytest.mark.parametrize("content", ["", "HEADER"], ids=["empty", "header only"])
def test_a_prior_journal_without_answers_is_refused(earlier_journal, tiny_kwargs, tmp_path, content):
    prior = tmp_path / "prior.jsonl"
    prior.write_text(earlier_journal.read_text().splitlines(keepends=True)[0] if content else "")
    with pytest.raises(ValueError, match=r"prior_preferences .*prior.jsonl holds no answers"):
        PEBBLE("MlpPolicy", "Pendulum-v1", preference_journal=tmp_path / "own.jsonl", prior_preferences=[prior], **tiny_kwargs)
    assert not (tmp_path / "own.jsonl").exists()


def test_a_line_that_is_not_a_journal_entry_is_named_with_its_file_and_line(earlier_journal, tiny_kwargs, tmp_path):
    for name, lines in (
        ("foreign.jsonl", ['{"a": 1}']),
        ("bad_inputs.jsonl", ['{"session": 1, "label": 1.0, "shape": [2, 10, 4], "inputs": "AAAA"}']),
    ):
        prior = tmp_path / name
        prior.write_text(earlier_journal.read_text() + "\n".join(lines) + "\n")
        with pytest.raises(ValueError, match=rf"prior_preferences .*{name}: line 62 is not a journal entry"):
            PEBBLE("MlpPolicy", "Pendulum-v1", prior_preferences=[prior], **tiny_kwargs)
    own = tmp_path / "own.jsonl"
    own.write_text('{"a": 1}\n')
    with pytest.raises(ValueError, match=r"preference_journal .*own.jsonl: line 1 is not a journal entry"):
        PEBBLE("MlpPolicy", "Pendulum-v1", preference_journal=own, **tiny_kwargs)


@pytest.mark.filterwarnings("ignore:the budget cannot be asked")
def test_a_saved_model_loads_from_any_folder_its_journal_found_beside_it(tiny_kwargs, tmp_path, monkeypatch):
    project = tmp_path / "project"
    project.mkdir()
    monkeypatch.chdir(project)
    model = PEBBLE("MlpPolicy", "Pendulum-v1", seed=0, preference_journal="run/pend.jsonl", **tiny_kwargs).learn(700)
    model.save("run/model.zip")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    # run/pend.jsonl, relative to the folder the run was made in: found from the model file's folder up
    loaded = PEBBLE.load(project / "run" / "model.zip", env=gym.make("Pendulum-v1"))
    assert os.path.samefile(loaded.preference_journal, project / "run" / "pend.jsonl")
    assert loaded.feedback.journal.included == 40
    loaded.learn(300, reset_num_timesteps=False)  # the third session is journaled where the first two are
    assert len(PreferenceJournal(project / "run" / "pend.jsonl").read()) == 60
    assert not (elsewhere / "run").exists()
    # a journal path relative to the model's own folder, and a journal moved beside its model
    monkeypatch.chdir(project / "run")
    relative = PEBBLE("MlpPolicy", "Pendulum-v1", seed=0, preference_journal="logs/pend.jsonl", **tiny_kwargs).learn(400)
    relative.save("model2.zip")
    monkeypatch.chdir(elsewhere)
    assert os.path.samefile(PEBBLE.load(project / "run" / "model2.zip").preference_journal, project / "run/logs/pend.jsonl")
    (project / "run" / "logs" / "pend.jsonl").rename(project / "run" / "pend2.jsonl")
    relative.preference_journal = str(project / "run" / "logs" / "pend2.jsonl")  # an absolute path, since moved
    relative.save(project / "run" / "model2.zip")
    assert os.path.samefile(PEBBLE.load(project / "run" / "model2.zip").preference_journal, project / "run/pend2.jsonl")
    # a journal that is gone is said to be missing; load(preference_journal=None) loads the model without it
    (project / "run" / "pend.jsonl").unlink()
    with pytest.raises(ValueError, match=r"preference_journal run/pend.jsonl is missing.*40 answers.*preference_journal="):
        PEBBLE.load(project / "run" / "model.zip")
    assert len(PEBBLE.load(project / "run" / "model.zip", preference_journal=None).preferences) == 40
