"""The one compiled kernel (decode+bin of packed planes); everything else is in pyproject.toml.

``optional=True``: where no C compiler is available the install still succeeds and
``rmbvideo.sensor.binning`` falls back to its numpy path (bit for bit the same, slower).
"""

from setuptools import Extension, setup

setup(
    ext_modules=[
        Extension(
            "rmbvideo.sensor._packed",
            sources=["rmbvideo/sensor/_packed.c"],
            extra_compile_args=["-O3"],
            optional=True,
        )
    ]
)
