"""A robot model from what a user names: a built-in robot, a model YAML file or a URDF chain."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from relcal.errors import RelcalError
from relcal.robot.model import RobotModel, library_names, load_model
from relcal.robot.urdf import load_urdf


def get_robot(
    name_or_path: str | Path,
    root: str | None = None,
    tip: str | None = None,
    parametrisation: str = "minimal",
) -> RobotModel:
    """A robot model: built-in by name, a model YAML file, or a URDF chain.

    Parameters
    ----------
    name_or_path : str or Path
        A built-in robot's name (``a465``, ``puma560``, ...), a model YAML file (``.yaml``,
        ``.yml``) or a URDF file (``.urdf``).
    root, tip : str, optional
        The URDF chain's first and last links; may be omitted when the tree has one obvious
        serial chain. URDF files only.
    parametrisation : {"minimal", "origins"}
        For URDF robots, the error parameters :func:`relcal.make_layout` gives: the DH
        parameters, or per joint a small motion of its URDF origin and a zero offset (see
        :func:`relcal.load_urdf`).

    Returns
    -------
    RobotModel
        The nominal model, lengths in m and angles in rad.

    Raises
    ------
    ArgumentError
        ``name_or_path`` not a string or path, or an unknown ``parametrisation``.
    RelcalError
        An unknown robot name, a file that cannot be read as a model, or ``root``/``tip`` given
        for a file that is not a URDF.

    Examples
    --------
    >>> import relcal
    >>> relcal.get_robot("a465")
    <RobotModel 'Thermo CRS A465': 6 joints, standard DH>
    """
    from relcal.checks import check_choice, check_path

    name = str(check_path(name_or_path, "name_or_path", "a robot name or a file path"))
    check_choice(parametrisation, "parametrisation", ("minimal", "origins"))
    if Path(name).suffix.lower() in (".urdf", ".xacro"):
        return load_urdf(name, root, tip, parametrisation)
    if root is not None or tip is not None:
        raise RelcalError(f"robot '{name}': root and tip links apply to URDF files (.urdf) only")
    if name.lower() in library_names():
        ref = resources.files("relcal.robot") / "library" / f"{name.lower()}.yaml"
        with resources.as_file(ref) as path:
            return load_model(path)
    if Path(name).suffix in (".yaml", ".yml") or Path(name).exists():
        return load_model(name)
    raise RelcalError(
        f"unknown robot '{name}': expected one of {', '.join(library_names())}, a model YAML file "
        "path or a URDF file (.urdf)"
    )


def library_by_title(title: str) -> str | None:
    """The built-in robot (its short name, ``ur5e``) whose model is named ``title``
    (``Universal Robots UR5e``), or None."""
    for name in library_names():
        ref = resources.files("relcal.robot") / "library" / f"{name}.yaml"
        with resources.as_file(ref) as path:
            if load_model(path).name == title:
                return name
    return None
