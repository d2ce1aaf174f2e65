import pytest

from perceptual_uv.core.settings import OptimizeSettings


def test_defaults_are_the_papers():
    settings = OptimizeSettings()
    assert (settings.epsilon, settings.iterations, settings.screen_pixels) == (0.01, 100, 64)
    assert settings.uv_map_name == "PerceptualUV"


def test_views_grow_by_default_to_the_core_limit():
    from perceptual_uv.core.camera import MAX_SCREEN_PIXELS

    assert OptimizeSettings().max_screen_pixels == MAX_SCREEN_PIXELS == 256
    assert OptimizeSettings(screen_pixels=32, max_screen_pixels=32).max_screen_pixels == 32


@pytest.mark.parametrize("field, value, fragment", [
    ("epsilon", 0.0, "epsilon"), ("target_cost", 0.0, "target cost"), ("resolution", 4, "resolution"),
    ("iterations", 5, "iterations"), ("screen_pixels", 63, "screen pixels"), ("workers", -1, "workers"),
    ("uv_map_name", " ", "name"), ("max_screen_pixels", 48, "largest view"), ("max_screen_pixels", 99, "largest view"),
    ("max_screen_pixels", 512, "largest view"),
])
def test_bad_values_are_refused_with_the_field_named(field, value, fragment):
    with pytest.raises(ValueError, match=fragment):
        OptimizeSettings(**{field: value})


def test_explicit_resolution_ignores_the_cost():
    assert OptimizeSettings(resolution=512, target_cost=0.0).resolution == 512


def test_the_cost_is_image_memory_unless_texels_are_asked_for():
    assert OptimizeSettings().cost_measure == "memory"
    assert OptimizeSettings(cost_measure="texels").cost_measure == "texels"
    with pytest.raises(ValueError, match=r"cost measure 'bytes': must be 'memory' .* or 'texels' \(the paper's "
                                         r"relative texel cost, Eq. 21\)"):
        OptimizeSettings(cost_measure="bytes")
