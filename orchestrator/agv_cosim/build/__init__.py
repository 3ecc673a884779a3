"""Building FMUs and shipping what goes with them (``agv-cosim build``, ``agv-cosim
examples``).

- :mod:`.fmus`: the component FMUs from the slave scripts of ``agv_core`` (loader and
  bridge compiled in, reference result, build index); its public names are this
  package's.
- :mod:`.bundle`: what an FMU ships of ``agv_core`` and the distributions it pins.
- :mod:`.standalone`: the Python runtime a standalone FMU carries.
- :mod:`.examples`: copies of the shipped experiment manifests for a user's folder.
- :mod:`.shipped`: where the files shipped besides the packages are (checkout or wheel).

The names of :mod:`.fmus` are loaded on first use (PEP 562), so that ``agv-cosim
examples``, which needs :mod:`.examples` only, does not import pythonfmu and fmpy.
"""

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from .fmus import (
        BOOT_SCRIPT,
        BOOT_SOURCE,
        BRIDGE_SOURCE,
        BRIDGE_SUFFIX,
        BUILD_FORMAT,
        BUNDLE_FOLDER,
        FMI3_ALIAS,
        FMI3_BODY_SUFFIX,
        FMI3_WRAPPER_SUFFIX,
        FMI_VERSIONS,
        INDEX_FILE,
        LOADER_SOURCE,
        RECORD_FORMAT,
        REFERENCE_DIR,
        REFERENCE_MANIFEST,
        SLAVE_PATTERN,
        BuildError,
        BuildResult,
        build_fmus,
        build_one,
        check_replaceable,
        component_scripts,
        default_components_dir,
        fmi3_wrapper_source,
        fmu_guid,
        fmu_guid_of,
        host_python,
        loader_binary,
        read_record,
        reference_experiment,
        reference_input_rows,
        simulate_reference,
        slave_class_name,
        slave_script,
        slave_scripts,
    )

__all__ = ["BOOT_SCRIPT", "BOOT_SOURCE", "BRIDGE_SOURCE", "BRIDGE_SUFFIX", "BUILD_FORMAT",
           "BUNDLE_FOLDER", "FMI3_ALIAS", "FMI3_BODY_SUFFIX", "FMI3_WRAPPER_SUFFIX",
           "FMI_VERSIONS", "INDEX_FILE", "LOADER_SOURCE", "RECORD_FORMAT", "REFERENCE_DIR",
           "REFERENCE_MANIFEST", "SLAVE_PATTERN", "BuildError", "BuildResult",
           "build_fmus", "build_one", "check_replaceable", "component_scripts",
           "default_components_dir", "fmi3_wrapper_source", "fmu_guid", "fmu_guid_of",
           "host_python", "loader_binary", "read_record", "reference_experiment",
           "reference_input_rows", "simulate_reference", "slave_class_name",
           "slave_script", "slave_scripts"]


def __getattr__(name: str) -> Any:
    """A public name of :mod:`.fmus`, imported on first use."""
    if name not in __all__:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    from . import fmus

    value = getattr(fmus, name)
    globals()[name] = value
    return value
