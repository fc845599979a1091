"""Our bake's I_z against Cycles' Diffuse bake (Direct + Indirect, Color off), light by light.

Tolerance (see cycles_compare.assert_agree): both estimators are run twice with different
seeds; the spread gives each one's per-texel noise, from which the expected residual RMS and
the standard error of the mean difference follow. A 1% allowance covers what is not noise."""
import math

import numpy as np
import pytest

import cycles_compare as cc

pytestmark = [pytest.mark.bpy, pytest.mark.slow]


@pytest.fixture
def floor(extension):
    cc.clear_scene()
    f = cc.plane("Floor", (0, 0, 0), 2.0, cc.material("Floor", (0.8, 0.8, 0.8)))
    cc.box("Blocker", (0.2, 0.1, 0.35), (0.4, 0.4, 0.3), cc.material("Blocker", (0.6, 0.5, 0.4)))
    cc.unwrap([f])
    return f


def test_sun(floor):
    cc.light('SUN', rotation=(math.radians(30), math.radians(10), 0), energy=3.0, angle=0.0)
    r = cc.compare([floor], samples=32, bounces=1)
    assert r["mean"] > 0.3
    cc.assert_agree(r)


def test_sun_with_angle(floor):
    cc.light('SUN', rotation=(math.radians(35), 0, 0), energy=3.0, angle=math.radians(12))
    cc.assert_agree(cc.compare([floor], samples=64, bounces=1))


def test_point(floor):
    cc.light('POINT', location=(-0.3, -0.2, 1.2), energy=300.0, shadow_soft_size=0.0)
    cc.assert_agree(cc.compare([floor], samples=32, bounces=1))


@pytest.mark.parametrize("soft_falloff", [True, False])
def test_point_with_radius(floor, soft_falloff):
    lamp = cc.light('POINT', location=(-0.3, -0.2, 1.2), energy=300.0, shadow_soft_size=0.25)
    lamp.data.use_soft_falloff = soft_falloff      # disk facing the point (default) or sphere
    cc.assert_agree(cc.compare([floor], samples=64, bounces=1))


def test_constant_world(floor):
    cc.world((0.4, 0.6, 1.0))
    cc.assert_agree(cc.compare([floor], samples=64, bounces=1))


def test_emissive_mesh(floor):
    cc.plane("Lamp", (0, 0, 1.0), 0.8, cc.material("Lamp", (0.0, 0.0, 0.0), emission=(1.0, 0.9, 0.7, 8.0)),
             rotation=(math.pi, 0, 0))
    cc.assert_agree(cc.compare([floor], samples=128, bounces=1))
