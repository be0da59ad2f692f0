"""Every built-in estimator passes the conformance suite; the registry behaves as documented."""
import dataclasses

import numpy as np
import pytest

from iblbench.estimators import registry
from iblbench.estimators.base import Estimator, Setting, Tags
from iblbench.estimators.light_pool import PoolParams
from iblbench.estimators.uniform import Uniform
from iblbench.harness.verify.conformance import (Harness, check_estimator, check_setting_properties,
                                                 check_settings_differ, parametrize_with_checks)
from iblbench.foundation.errors import InputError

BUILTINS = [registry.make_estimator(name) for name in registry.builtin_names()]


@parametrize_with_checks(BUILTINS)
def test_builtin_conformance(estimator, check):
    check(estimator)


def test_registry_is_case_insensitive_and_lists_valid_names():
    assert type(registry.make_estimator("UNIFORM")).name == "uniform"
    with pytest.raises(InputError, match=r"unknown estimator 'nope'; valid estimators: .*uniform"):
        registry.make_estimator("nope")


def test_params_are_stored_not_acted_on():
    @dataclasses.dataclass(frozen=True)
    class PluginParams:
        boost: float = 1.0

    class Plugin(Estimator):
        name = "test-plugin"
        Params = PluginParams

    plugin = Plugin(boost=2.0)
    assert plugin.params == PluginParams(boost=2.0)
    with pytest.raises(TypeError):
        Plugin(unknown=1)


class _Biased(Estimator):
    """A plugin that scales a correct estimator by 1.2: the suite must reject it."""

    name = "test-biased"
    tags = Tags(unbiased=True, has_pdf=False)
    requires = ("cdf",)

    def render(self, gbuffer, cache, spp, seed):
        estimate = registry.make_estimator("uniform").render(gbuffer, cache, spp, seed)
        estimate.radiance = estimate.radiance * np.float32(1.2)
        return estimate


def test_check_estimator_rejects_a_biased_plugin_and_records_known_failures():
    with pytest.raises(AssertionError, match="check_unbiased"):
        check_estimator(_Biased())
    outcome = check_estimator(_Biased(), expected_failed_checks={
        "check_unbiased": "scaled by 1.2 on purpose",
        "check_white_furnace": "scaled by 1.2 on purpose",
        "check_convergence": "scaled by 1.2 on purpose: the bias floor stops the error falling"})
    assert outcome["check_unbiased"].startswith("xfail: scaled")
    assert outcome["check_white_furnace"].startswith("xfail")
    assert outcome["check_deterministic"] == "passed"
    assert outcome["check_matches_twin"].startswith("skipped: no independent NumPy twin")


@dataclasses.dataclass(frozen=True)
class _UnusedParams(PoolParams):
    unused: int = 0


class _Unused(Uniform):
    """``uniform`` with a parameter it never reads: a setting that is silently ignored."""

    name = "test-unused"
    Params = _UnusedParams
    settings = Uniform.settings + (Setting("unused", 1),)


def test_settings_checks_reject_an_ignored_an_undeclared_and_an_unstated_parameter(compute):
    """The settings checks fail where they must: a parameter that changes nothing, one with no
    declared Setting, and a Setting that says a property the suite does not know."""
    h = Harness(compute)
    with pytest.raises(AssertionError, match=r"renders exactly as with the default: unused = 1$"):
        check_settings_differ(_Unused(), h)

    class Undeclared(_Unused):
        settings = Uniform.settings

    with pytest.raises(AssertionError, match="no Setting off their default .*: unused$"):
        check_settings_differ(Undeclared(), h)

    class Unknown(_Unused):
        settings = (Setting("shared_sequence", False, says="no-such-property"),)

    with pytest.raises(AssertionError, match="no property check 'no-such-property'"):
        check_setting_properties(Unknown(), h)
