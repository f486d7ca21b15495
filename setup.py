"""Build hook for the optional compiled cores: the plant (hilbench/plant/_plantcore.c), the
AN1017 board firmware (firmware/an1017/an1017.c on the runtime firmware/runtime/hrt.c, behind the
glue hilbench/targets/an1017/_core.c) and the F2812 FOC firmware (firmware/foc/*.c behind the glue
hilbench/targets/foc/_core.c), the session's C span (hilbench/bench/_span.c) and the NPZ archive's
background column writer (hilbench/bench/_npzcolumns.c).

All metadata is in pyproject.toml. The extension is `optional`: without a C compiler
`pip install .` still succeeds and hilbench.plant falls back to its pure-Python step
(and hilbench.targets.an1017 to its pure-Python firmware model).
-ffp-contract=off keeps the C arithmetic identical to the Python backend (no fused multiply-add).
The three extensions share their CPython glue: hilbench/_cglue/hbglue.h, a header on each one's
include path.
"""

import sys

from setuptools import Extension, setup

#: the CPython glue every extension shares (a header; MANIFEST.in ships it in the sdist)
GLUE = ["hilbench/_cglue"]
GLUE_HEADER = ["hilbench/_cglue/hbglue.h"]

if sys.platform == "win32":
    _flags: list[str] = ["/O2", "/fp:precise"]
else:
    _flags = ["-O2", "-std=c99", "-ffp-contract=off", "-fno-fast-math"]

setup(
    ext_modules=[
        Extension(  # the session's lockstep span in C: the plant's and the target's C steps through their capsules
            "hilbench.bench._span",
            sources=["hilbench/bench/_span.c"],
            include_dirs=GLUE,
            depends=GLUE_HEADER,
            extra_compile_args=_flags,
            optional=True,
        ),
        Extension(  # the process paths in C (RemoteTarget.step for the C span, serve()'s loop) on protocol 3's C library
            "hilbench.targets._remotestep",
            sources=["hilbench/targets/_remotestep.c", "firmware_protocol/hbp.c", "firmware_protocol/hbp_codec.c",
                     "firmware_protocol/hbp_messages.c"],
            include_dirs=GLUE + ["firmware_protocol"],
            depends=GLUE_HEADER + ["firmware_protocol/hbp.h", "firmware_protocol/hbp_messages.h"],
            extra_compile_args=_flags,
            optional=True,
        ),
        Extension(  # an NPZ archive's columns written on a thread while the run goes on (the journal path is the reference)
            "hilbench.bench._npzcolumns",
            sources=["hilbench/bench/_npzcolumns.c"],
            depends=["hilbench/bench/_rawfields.h", "hilbench/bench/_writerthread.h",  # a raw row's fields as columns, shared with _csvrows
                     "hilbench/bench/_crc32.h"],
            extra_compile_args=_flags + (["-pthread"] if sys.platform != "win32" else []),
            extra_link_args=["-pthread"] if sys.platform != "win32" else [],
            optional=True,
        ),
        Extension(  # CSV rows in C from raw rows, on a thread (Recorder._format_csv is the reference)
            "hilbench.bench._csvrows",
            sources=["hilbench/bench/_csvrows.c"],
            depends=["hilbench/bench/_rawfields.h", "hilbench/bench/_writerthread.h"],
            extra_compile_args=_flags + (["-pthread"] if sys.platform != "win32" else []),
            extra_link_args=["-pthread"] if sys.platform != "win32" else [],
            optional=True,
        ),
        Extension(
            "hilbench.plant._plantcore",
            sources=["hilbench/plant/_plantcore.c"],
            include_dirs=GLUE,
            depends=GLUE_HEADER + ["hilbench/plant/_switching.c"],  # included by _plantcore.c
            extra_compile_args=_flags,
            optional=True,
        ),
        Extension(  # the FOC firmware's own source behind a CPython glue (MANIFEST.in ships it)
            "hilbench.targets.foc._core",
            sources=["hilbench/targets/foc/_core.c", "firmware/foc/foc.c", "firmware/foc/foc_blocks.c",
                     "firmware/foc/foc_sin_table.c"],
            include_dirs=GLUE + ["firmware/foc"],
            depends=GLUE_HEADER + ["firmware/foc/foc.h", "firmware/foc/foc_blocks.h", "firmware/foc/foc_config.h",
                                   "firmware/foc/iq24.h"],
            extra_compile_args=_flags,
            optional=True,
        ),
        Extension(  # the board firmware's own source on the runtime behind a CPython glue (MANIFEST.in ships them)
            "hilbench.targets.an1017._core",
            sources=["hilbench/targets/an1017/_core.c", "firmware/an1017/an1017.c", "firmware/runtime/hrt.c"],
            include_dirs=GLUE + ["firmware/an1017", "firmware/runtime", "firmware_protocol"],
            depends=GLUE_HEADER + ["firmware/an1017/an1017.h", "firmware/an1017/q15.h", "firmware/an1017/hrt_config.h",
                                   "firmware/runtime/hrt.h", "firmware_protocol/hbp_messages.h"],
            extra_compile_args=_flags,
            optional=True,
        ),
    ]
)
