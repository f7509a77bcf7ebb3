"""
Bad input, systematically: property-based tests with Hypothesis.

1. Constructors. Every validated parameter of PEBBLE and PRIDE (PEBBLE's also through PRIDE; the reward learner's,
   the query sampler's and pre-training's through ``reward_kwargs``, ``query_kwargs`` and ``pretraining_kwargs``, the
   generator's through ``generator_kwargs``) refuses values drawn
   from outside what it accepts (out-of-range integers, non-integers where an integer is required, NaN and ±inf,
   bools, strings, None, unknown choices) with a ``ValueError`` that names the parameter and the accepted range.
   Values drawn from inside the range construct, and the model keeps them. A structured setting refuses names it does
   not know, naming the setting.
2. The teacher boundary. The model's ``feedback.ask`` and the feedback session inside ``learn()`` refuse a teacher's
   answer of the wrong length, or with a label outside [0, 1] (±inf included), with a ``ValueError``; then nothing
   is recorded: ``preferences``, ``phase.asked`` / ``phase.labeled`` / ``phase.sessions``, the journal
   entries the run includes (``feedback.journal.included``) and the preference journal are as before. Labels drawn
   from {0, 0.5, 1, NaN} and [0, 1] are accepted and counted: every query as asked, the non-NaN ones as labeled and
   added to the preferences.

The holes they found (each failed before its fix) have their own tests at the end.
"""

import math
import re
from dataclasses import dataclass

import numpy as np
import pytest
from conftest import TINY
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from sb3_pride import PEBBLE, PRIDE
from sb3_pride.common.teachers import TEACHERS
from sb3_pride.pride.diffusion import NORMALIZATIONS
from sb3_pride.pride.generator import FILTERS, GENERATIONS
from sb3_pride.common.journal import PreferenceJournal
from sb3_pride.common.queries import SegmentPairs
from sb3_pride.common.query_selection import QUERY_SELECTIONS
from sb3_pride.reward.learner import RewardLearner
from sb3_pride.common.utils import merge_kwargs

#: cheap models: Pendulum (200-step episodes), tiny networks, small buffers
CHEAP = dict(buffer_size=1000, policy_kwargs=dict(net_arch=[16]), reward_kwargs=dict(net_arch=(16,)))
CHEAP_PRIDE = dict(CHEAP, synthetic_samples=64)
#: invalid values raise before anything is built; valid ones build a model (a few ms each)
FAST = settings(max_examples=25, deadline=None, database=None)
BUILDS = settings(max_examples=10, deadline=None, database=None)
SESSIONS = settings(
    max_examples=20, deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large]
)


#: PRIDE's generator settings, given through generator_kwargs
GENERATOR_PARAMS = {"width", "n_blocks", "train_steps", "sample_steps", "window", "generation", "normalization",
                    "anchor_noise", "keep_quantile", "filter", "diffusion_kwargs", "dynamics_kwargs"}  # fmt: skip


#: PEBBLE's structured settings, whose entries are named "setting.key" here (e.g. "reward_kwargs.epochs")
STRUCTURED = ("reward_kwargs", "query_kwargs", "pretraining_kwargs")


def build(algo, **kwargs):
    """``algo`` on Pendulum, cheap, with ``kwargs``: "setting.key" into its structured setting, the generator's into
    ``generator_kwargs``."""
    nested: dict = {}
    for name in list(kwargs):
        if "." in name:
            setting, key = name.split(".")
            nested.setdefault(setting, {})[key] = kwargs.pop(name)
        elif name in GENERATOR_PARAMS:
            nested.setdefault("generator_kwargs", {})[name] = kwargs.pop(name)
    return algo("MlpPolicy", "Pendulum-v1", **merge_kwargs(CHEAP_PRIDE if algo is PRIDE else CHEAP, {**kwargs, **nested}))


def setting(model, param):
    """A constructor setting as the model keeps it (a structured setting's entry in it, the generator's on its
    generator)."""
    if "." in param:
        name, key = param.split(".")
        return getattr(model, name)[key]
    if param in GENERATOR_PARAMS:
        return model.generator.diffusion_options.get(param, getattr(model.generator, param, None))
    return getattr(model, param)


# -- strategies of bad values --------------------------------------------------------------------------------------
def numpy_ints(min_value: int, max_value: int) -> st.SearchStrategy:
    return st.integers(min_value, max_value).map(np.int64)


def non_integers(none: bool = True) -> st.SearchStrategy:
    """Never an integer: floats (integral ones, NaN and ±inf too), bools, strings, a list, and None unless it is valid."""
    values = [st.floats(), st.booleans(), st.text(max_size=4), st.lists(st.integers(), max_size=2)]
    return st.one_of(*values, *([st.none()] if none else []))


def not_positive_int(none: bool = True) -> st.SearchStrategy:
    return st.one_of(st.integers(max_value=0), numpy_ints(-(2**63), 0), non_integers(none))


def not_non_negative_int() -> st.SearchStrategy:
    return st.one_of(st.integers(max_value=-1), numpy_ints(-(2**63), -1), non_integers())


def negative_floats() -> st.SearchStrategy:
    """Floats < 0, -inf included (not -0.0, which equals 0)."""
    return st.floats(max_value=0.0, exclude_max=True).filter(lambda x: x < 0)


def floats_above(bound: float) -> st.SearchStrategy:
    """Floats > ``bound``, +inf included."""
    return st.floats(min_value=bound, exclude_min=True)


def not_one_of(choices) -> st.SearchStrategy:
    return st.one_of(st.text(max_size=12).filter(lambda s: s not in choices), st.none(), st.integers())


# -- the parameter table -------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Invalid:
    """``param`` refuses every value of ``values`` with a ValueError whose message holds ``expected``."""

    param: str
    values: st.SearchStrategy
    expected: str
    label: str = ""

    @property
    def id(self) -> str:
        return self.param + (f"-{self.label}" if self.label else "")

    @property
    def name(self) -> str:
        return named(self.param)


def named(param: str) -> str:
    """What an error names: an entry of reward_kwargs as "reward_kwargs: epochs", of the others by its key alone."""
    setting, _, key = param.rpartition(".")
    return f"{setting}: {key}" if setting == "reward_kwargs" else key


PEBBLE_POSITIVE = ("max_feedback", "feedback_interval", "queries_per_session", "segment_length")
#: in reward_kwargs, errors read "reward_kwargs: epochs must be ..."
REWARD_POSITIVE = ("reward_kwargs.ensemble_size", "reward_kwargs.batch_size", "reward_kwargs.epochs")
#: in query_kwargs and pretraining_kwargs, errors name the key alone
QUERY_POSITIVE = ("query_kwargs.candidates_multiplier", "query_kwargs.max_query_episodes", "pretraining_kwargs.entropy_k")
PEBBLE_NON_NEGATIVE = ("unsupervised_steps", "pretraining_kwargs.critic_reset_updates")
PRIDE_POSITIVE = ("diffusion_interval", "synthetic_samples", "width", "n_blocks", "train_steps", "sample_steps")
PRIDE_OPTIONAL_POSITIVE = ("synthetic_buffer_size", "window")  # None: the default
PRIDE_NON_NEGATIVE = ("synthetic_start", "synthetic_ramp")


def unknown_names(known) -> st.SearchStrategy:
    """A dict with at least one name that is not in ``known``."""
    names = st.text(min_size=1, max_size=12).filter(lambda name: name not in known)
    return st.dictionaries(names, st.integers(1, 5), min_size=1, max_size=3)


PEBBLE_INVALID = [
    *(
        Invalid(p, not_positive_int(), f"{named(p)} must be a positive integer")
        for p in (*PEBBLE_POSITIVE, *REWARD_POSITIVE, *QUERY_POSITIVE)
    ),
    *(Invalid(p, not_non_negative_int(), f"{named(p)} must be a non-negative integer") for p in PEBBLE_NON_NEGATIVE),
    Invalid("segment_length", st.integers(201, 10**9), "is longer than an episode of this env (200 steps)", "over-episode"),
    Invalid(
        "query_selection", not_one_of(tuple(QUERY_SELECTIONS)), f"query_selection must be one of {tuple(QUERY_SELECTIONS)}"
    ),
    Invalid("reward_kwargs.learning_rate", st.floats(max_value=0.0), "reward_kwargs: learning_rate must be > 0"),
    Invalid(
        "reward_kwargs.early_stop",
        st.one_of(st.floats(max_value=0.0), st.floats(min_value=1.0), st.booleans(), st.text(max_size=4)),
        "reward_kwargs: early_stop must be None (no early stop) or in (0, 1)",
    ),
    Invalid(
        "query_kwargs.hybrid_replay",
        st.one_of(negative_floats(), floats_above(1.0), st.just(math.nan), st.booleans(), st.none()),
        "hybrid_replay must be in [0, 1]",
    ),
    Invalid("reward_kwargs", unknown_names(RewardLearner.settings()), "reward_kwargs: unknown settings", "unknown"),
    Invalid(
        "query_kwargs",
        unknown_names({"candidates_multiplier", "max_query_episodes", "hybrid_replay"}),
        "query_kwargs must be a dict of QuerySampler's settings",
        "unknown",
    ),
    Invalid(
        "pretraining_kwargs",
        unknown_names({"entropy_k", "critic_reset_updates"}),
        "pretraining_kwargs: unknown settings",
        "unknown",
    ),
    Invalid("n_steps", st.integers().filter(lambda n: n != 1), "n_steps must be 1"),
    Invalid(
        "teacher",
        st.one_of(st.text(max_size=8).filter(lambda s: s not in TEACHERS), st.integers(), st.none()),
        "teacher must be",
    ),
]
PRIDE_INVALID = [
    Invalid(
        "synthetic_ratio",
        st.one_of(negative_floats(), floats_above(1.0), st.just(math.nan)),
        "synthetic_ratio must be in [0, 1]",
    ),
    *(Invalid(p, not_positive_int(), f"{p} must be a positive integer") for p in PRIDE_POSITIVE),
    *(Invalid(p, not_positive_int(none=False), f"{p} must be a positive integer") for p in PRIDE_OPTIONAL_POSITIVE),
    *(Invalid(p, not_non_negative_int(), f"{p} must be a non-negative integer") for p in PRIDE_NON_NEGATIVE),
    Invalid("generation", not_one_of(GENERATIONS), f"generation must be one of {GENERATIONS}"),
    Invalid("normalization", not_one_of(NORMALIZATIONS), f"normalization must be one of {NORMALIZATIONS}"),
    Invalid(
        "anchor_noise",
        st.one_of(st.floats(max_value=0.002), floats_above(80.0), st.just(math.nan)),
        "anchor_noise must be in (sigma_min=0.002, sigma_max=80.0]",
    ),
    Invalid(
        "keep_quantile",
        st.one_of(st.floats(max_value=0.0), floats_above(1.0), st.just(math.nan)),
        "keep_quantile must be in (0, 1]",
    ),
    Invalid("filter", not_one_of(FILTERS), f"filter must be one of {FILTERS}"),
    Invalid(
        "synthetic_on_top",
        st.one_of(st.integers(), st.floats(), st.text(max_size=4), st.none()),
        "synthetic_on_top must be True or False",
    ),
]
INVALID = [
    pytest.param(algo, case, id=f"{algo.__name__}-{case.id}")
    for algo, cases in ((PEBBLE, PEBBLE_INVALID), (PRIDE, PEBBLE_INVALID + PRIDE_INVALID))
    for case in cases
]

VALID = [
    (PEBBLE, "segment_length", st.one_of(st.integers(1, 200), numpy_ints(1, 200))),
    (PEBBLE, "queries_per_session", st.one_of(st.integers(1, 10**9), numpy_ints(1, 10**9))),
    (PEBBLE, "max_feedback", st.integers(1, 10**12)),
    (PEBBLE, "query_kwargs.candidates_multiplier", st.integers(1, 10**6)),
    (PEBBLE, "query_kwargs.max_query_episodes", st.one_of(st.integers(1, 10**6), numpy_ints(1, 10**6))),
    (PEBBLE, "query_kwargs.hybrid_replay", st.floats(0.0, 1.0)),
    (PEBBLE, "unsupervised_steps", st.integers(0, 10**12)),
    (PEBBLE, "pretraining_kwargs.critic_reset_updates", st.one_of(st.integers(0, 10**6), numpy_ints(0, 10**6))),
    (PEBBLE, "pretraining_kwargs.entropy_k", st.integers(1, 10**6)),
    (PEBBLE, "query_selection", st.sampled_from(tuple(QUERY_SELECTIONS))),
    (PEBBLE, "reward_kwargs.learning_rate", st.floats(min_value=0.0, max_value=1e3, exclude_min=True)),
    (PEBBLE, "reward_kwargs.epochs", st.one_of(st.integers(1, 10**6), numpy_ints(1, 10**6))),
    (PEBBLE, "reward_kwargs.early_stop", st.one_of(st.none(), st.floats(0.0, 1.0, exclude_min=True, exclude_max=True))),
    (PRIDE, "synthetic_ratio", st.floats(0.0, 1.0, exclude_max=True)),
    (PRIDE, "diffusion_interval", st.integers(1, 10**12)),
    (PRIDE, "synthetic_buffer_size", st.one_of(st.none(), st.integers(1, 1000))),
    (PRIDE, "window", st.one_of(st.none(), st.integers(1, 10**12))),
    (PRIDE, "synthetic_start", st.integers(0, 10**12)),
    (PRIDE, "synthetic_ramp", st.integers(0, 10**12)),
    (PRIDE, "generation", st.sampled_from(GENERATIONS)),
    (PRIDE, "normalization", st.sampled_from(NORMALIZATIONS)),
    (PRIDE, "anchor_noise", st.floats(0.002, 80.0, exclude_min=True)),
    (PRIDE, "keep_quantile", st.floats(0.0, 1.0, exclude_min=True)),
    (PRIDE, "filter", st.sampled_from(FILTERS)),
]


@pytest.mark.parametrize(("algo", "case"), INVALID)
@FAST
@given(data=st.data())
def test_invalid_values_are_refused_naming_the_parameter(algo, case, data):
    value = data.draw(case.values, label=case.param)
    with pytest.raises(ValueError, match=re.escape(case.name)) as error:
        build(algo, **{case.param: value})
    assert case.expected in str(error.value)


@pytest.mark.parametrize(("algo", "param", "values"), [pytest.param(*v, id=f"{v[0].__name__}-{v[1]}") for v in VALID])
@BUILDS
@given(data=st.data())
def test_valid_values_construct(algo, param, values, data):
    value = data.draw(values, label=param)
    model = build(algo, **{param: value})
    assert setting(model, param) == value


# -- the teacher boundary ------------------------------------------------------------------------------------------
#: pre-training ends at step 40, and a session asks N_PAIRS queries of 5-step segments
SESSION = merge_kwargs(
    merge_kwargs(TINY, CHEAP),
    dict(
        learning_starts=20,
        unsupervised_steps=20,
        segment_length=5,
        queries_per_session=8,
        max_feedback=10**6,
        feedback_interval=10**6,
        batch_size=16,
        reward_kwargs=dict(epochs=2),
        pretraining_kwargs=dict(critic_reset_updates=2),
    ),
)
N_PAIRS = SESSION["queries_per_session"]

VALID_LABELS = st.one_of(st.sampled_from([0.0, 0.5, 1.0, math.nan]), st.floats(0.0, 1.0))
OUT_OF_RANGE_LABELS = st.one_of(st.sampled_from([math.inf, -math.inf]), negative_floats(), floats_above(1.0))


def float32_array(labels) -> np.ndarray:
    return np.array(labels, dtype=np.float32)


#: how a teacher may hand its labels back, exactly
EXACT_CONTAINERS = st.sampled_from([list, tuple, np.array])
#: ... or rounded to float32 (not for out-of-range labels: 1 + 1e-16 would round into [0, 1])
CONTAINERS = st.one_of(EXACT_CONTAINERS, st.just(float32_array))


@st.composite
def labels_of_wrong_length(draw, n_pairs: int = N_PAIRS):
    """Valid labels, but not one per pair: none, too few, too many, or one bare number."""
    n = draw(st.integers(0, 3 * n_pairs).filter(lambda n: n != n_pairs))
    if n == 1 and draw(st.booleans()):
        return draw(VALID_LABELS)
    return draw(CONTAINERS)(draw(st.lists(VALID_LABELS, min_size=n, max_size=n)))


@st.composite
def labels_out_of_range(draw, n_pairs: int = N_PAIRS):
    """One label per pair, at least one of them outside [0, 1] (±inf included)."""
    labels = draw(st.lists(VALID_LABELS, min_size=n_pairs, max_size=n_pairs))
    for index in draw(st.lists(st.integers(0, n_pairs - 1), min_size=1, max_size=n_pairs, unique=True)):
        labels[index] = draw(OUT_OF_RANGE_LABELS)
    return draw(EXACT_CONTAINERS)(labels)


class EchoTeacher:
    """A custom teacher that answers what it is told to: ``labels``, or ``labels(n_pairs)`` if callable."""

    def __init__(self):
        self.labels = None
        self.asked: list[int] = []  # how many pairs each call asked about

    def __call__(self, pairs: SegmentPairs):
        self.asked.append(len(pairs))
        return self.labels(len(pairs)) if callable(self.labels) else self.labels


def model_at_first_session(journal) -> PEBBLE:
    """A PEBBLE whose pre-training is over: its next env step opens the first feedback session."""
    model = PEBBLE("MlpPolicy", "Pendulum-v1", seed=0, teacher=EchoTeacher(), preference_journal=journal, **SESSION)
    model.learn(model.phase.next_step - 1)
    assert model.teacher.asked == [] and model.phase.sessions == 0
    return model


def session_at_next_step(model: PEBBLE, labels) -> None:
    """One more env step in ``learn()``, which opens a feedback session answered with ``labels``."""
    model.teacher.labels = labels
    model.phase.next_step = model.num_timesteps + 1
    model.learn(1, reset_num_timesteps=False)


def feedback_record(model: PEBBLE) -> dict:
    """Everything a feedback session records."""
    return dict(
        asked=model.phase.asked,
        labeled=model.phase.labeled,
        sessions=model.phase.sessions,
        journal_entries=model.feedback.journal.included,
        journal=len(PreferenceJournal(model.preference_journal).read()),
        inputs=model.preferences.inputs.copy(),
        labels=model.preferences.labels.copy(),
    )


def assert_same_record(before: dict, after: dict) -> None:
    for key in before:
        np.testing.assert_array_equal(after[key], before[key], err_msg=key)


@pytest.fixture(scope="module")
def refusing_model(tmp_path_factory):
    return model_at_first_session(tmp_path_factory.mktemp("refusing") / "journal.jsonl")


@pytest.fixture(scope="module")
def accepting_model(tmp_path_factory):
    return model_at_first_session(tmp_path_factory.mktemp("accepting") / "journal.jsonl")


@pytest.fixture(scope="module")
def bare_model():
    """For asking its teacher alone: no env step needed."""
    return build(PEBBLE, teacher=EchoTeacher())


def ask_teacher(model: PEBBLE, pairs: SegmentPairs) -> np.ndarray:
    """The model's teacher asked about ``pairs`` as in its next feedback session, the answer checked."""
    context = model.feedback.context(model.phase.sessions + 1, model.phase.asked, model.max_feedback)
    return model.feedback.ask(pairs, context)


def segment_pairs(n: int) -> SegmentPairs:
    return SegmentPairs(np.zeros((n, 2, 5, 3)), np.zeros((n, 2, 5, 1)), np.zeros((n, 2, 5)))


@SESSIONS
@given(n_pairs=st.integers(0, 12), data=st.data())
def test_ask_teacher_refuses_bad_labels(bare_model, n_pairs, data):
    labels = data.draw(
        labels_of_wrong_length(n_pairs)
        if n_pairs == 0
        else st.one_of(labels_of_wrong_length(n_pairs), labels_out_of_range(n_pairs)),
        label="labels",
    )
    bare_model.teacher.labels = labels
    with pytest.raises(ValueError, match="teacher"):
        ask_teacher(bare_model, segment_pairs(n_pairs))


@SESSIONS
@given(n_pairs=st.integers(0, 12), data=st.data())
def test_ask_teacher_accepts_valid_labels(bare_model, n_pairs, data):
    labels = data.draw(CONTAINERS)(data.draw(st.lists(VALID_LABELS, min_size=n_pairs, max_size=n_pairs), label="labels"))
    bare_model.teacher.labels = labels
    answer = ask_teacher(bare_model, segment_pairs(n_pairs))
    assert answer.shape == (n_pairs,) and answer.dtype == np.float64
    np.testing.assert_array_equal(answer, np.asarray(labels, dtype=np.float64))


@SESSIONS
@given(labels=labels_of_wrong_length())
def test_a_session_refuses_labels_of_the_wrong_length(refusing_model, labels):
    model = refusing_model
    before = feedback_record(model)
    with pytest.raises(ValueError, match=rf"teacher returned {np.size(labels)} labels for {N_PAIRS} segment pairs"):
        session_at_next_step(model, labels)
    assert model.teacher.asked[-1] == N_PAIRS
    assert_same_record(before, feedback_record(model))


@SESSIONS
@given(labels=labels_out_of_range())
def test_a_session_refuses_labels_outside_0_1(refusing_model, labels):
    model = refusing_model
    before = feedback_record(model)
    with pytest.raises(ValueError, match=r"teacher labels must be in \[0, 1\]"):
        session_at_next_step(model, labels)
    assert_same_record(before, feedback_record(model))


@SESSIONS
@given(labels=st.lists(VALID_LABELS, min_size=N_PAIRS, max_size=N_PAIRS), container=CONTAINERS)
def test_a_session_accepts_and_counts_valid_labels(accepting_model, labels, container):
    model = accepting_model
    before = feedback_record(model)
    session_at_next_step(model, lambda n_pairs: container(labels[:n_pairs]))
    # pairs already in the journal are never asked again: a late session may ask fewer than N_PAIRS
    asked = np.asarray(labels[: model.teacher.asked[-1]], dtype=np.float32)
    given_labels = asked[~np.isnan(asked)]
    after = feedback_record(model)
    assert after["asked"] == before["asked"] + len(asked)
    assert after["labeled"] == before["labeled"] + len(given_labels)
    assert after["sessions"] == before["sessions"] + 1
    assert after["journal_entries"] == before["journal_entries"] + len(asked)
    assert after["journal"] == before["journal"] + len(asked)
    assert len(after["labels"]) == len(before["labels"]) + len(given_labels)
    np.testing.assert_array_equal(after["labels"][len(before["labels"]) :], given_labels)
    np.testing.assert_array_equal(after["labels"][: len(before["labels"])], before["labels"])


# -- holes these tests found, fixed -------------------------------------------------------------------------------
@pytest.mark.parametrize("value", [math.nan, math.inf])
def test_reward_learning_rate_refuses_nan_and_inf(value):
    with pytest.raises(ValueError, match="reward_kwargs: learning_rate must be > 0"):
        build(PEBBLE, **{"reward_kwargs.learning_rate": value})


@pytest.mark.parametrize(
    ("algo", "param"),
    [
        (PEBBLE, "reward_kwargs.learning_rate"),
        (PEBBLE, "query_kwargs.hybrid_replay"),
        (PRIDE, "synthetic_ratio"),
        (PRIDE, "anchor_noise"),
        (PRIDE, "keep_quantile"),
    ],
)
@pytest.mark.parametrize("value", ["0.5", None])
def test_non_numbers_for_float_parameters_are_refused_naming_them(algo, param, value):
    with pytest.raises(ValueError, match=re.escape(named(param))):
        build(algo, **{param: value})


@pytest.mark.parametrize(
    ("param", "value"),
    [
        *((name, bad) for name in STRUCTURED for bad in ("paper", 3)),
        # a list of (name, value) pairs of a setting it knows
        *zip(STRUCTURED, ([("epochs", 5)], [("hybrid_replay", 0.5)], [("entropy_k", 5)]), strict=True),
    ],
)
def test_a_structured_setting_that_is_not_a_dict_is_refused_naming_it(param, value):
    with pytest.raises(ValueError, match=param):
        build(PEBBLE, **{param: value})


@pytest.mark.parametrize(
    ("param", "kwargs"),
    [
        ("diffusion", {"not_an_argument": 1}),
        ("diffusion", {"batch_size": 0}),
        ("dynamics_kwargs", {"width": 0}),
    ],
)
def test_bad_component_kwargs_are_refused_at_construction(param, kwargs):
    param = "diffusion_kwargs" if param == "diffusion" else param
    with pytest.raises(ValueError, match="diffusion" if param == "diffusion_kwargs" else param):
        build(PRIDE, **{param: kwargs})


@pytest.mark.parametrize(("n_pairs", "labels"), [(1, None), (3, [None, None, None]), (2, [0.0, None])])
def test_ask_teacher_refuses_none_labels(bare_model, n_pairs, labels):
    bare_model.teacher.labels = labels
    with pytest.raises(ValueError, match="teacher"):
        ask_teacher(bare_model, segment_pairs(n_pairs))


@pytest.mark.parametrize("labels", [["left", "right"], [{}, {}]], ids=["strings", "objects"])
def test_ask_teacher_refuses_non_numbers_naming_the_teacher(bare_model, labels):
    bare_model.teacher.labels = labels
    with pytest.raises(ValueError, match="teacher"):
        ask_teacher(bare_model, segment_pairs(2))
