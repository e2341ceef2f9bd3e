"""PETSc options the run can take, checked before anything is meshed.

The CLI checks the options database (command line, ``PETSC_OPTIONS``) with
:func:`petsc_option_problem` and refuses what the solvers cannot use with one line,
instead of failing after meshing and MBO (or crashing PETSc). Needs PETSc only to ask
which KSP, PC and line-search types are registered.
"""

import math
import re

from ufl_frames.bootstrap import init_petsc

__all__ = ["HESSIANS", "MAX_INT", "SIZE_HESSIANS", "TAO_TYPES", "petsc_option_problem"]

#: Largest iteration count accepted (PETSc's 32-bit ``PetscInt``).
MAX_INT = 2**31 - 1
#: The TAO types that run on this problem (objective, gradient, the Gauss–Newton Hessian
#: of ``solvers.SECOND_ORDER_TYPES``): every registered type was tried on the annulus
#: and the isotropic piano. The others fail for want of what they need (a Hessian
#: callback: gpcg, ipm, pdipm, bqpip, admm; constraints: almm, lcl; residuals: brgn,
#: pounders; a context: shell, python), meet the retraction's zero tensors (owlqn), or
#: crash PETSc (asils, asfls, ssils, ssfls, pounders).
TAO_TYPES = (
    "nls", "ntr", "ntl", "bnls", "bntr", "bntl", "tron",  # Newton (Gauss–Newton model)
    "lmvm", "blmvm", "bqnls", "bqnkls", "bqnktr", "bqnktl",  # quasi-Newton
    "bncg", "cg", "bmrm", "nm",  # conjugate gradient, bundle, Nelder–Mead
)
#: Values of ``-frames_hessian`` (the Newton model of ``solvers.hessian``).
HESSIANS = ("hybrid", "exact", "gauss_newton")
#: Values of ``-frames_size_hessian``: the size misfit's matrix where the Newton model is
#: exact (``fem.kernels.size_model_form``'s modes: 1, its second derivative, the default;
#: 2, its positive semidefinite modification; 0, its Gauss–Newton form).
SIZE_HESSIANS = {"exact": 1, "modified": 2, "gauss_newton": 0}
#: Options naming a PETSc type, by suffix: ``-mbo_ksp_type``, ``-tao_nls_pc_type``...
_TYPE_SUFFIX = re.compile(r"(?:^|.*_)(ksp|pc|ls)_type")
#: Integer options and their least value.
_INTS = {"tao_max_it": 1, "frames_active_rounds": 0, "frames_hessian_inertia_shifts": 0}
_NON_NEGATIVE_REALS = ("frames_gn_damping", "frames_gn_damping_min", "frames_hessian_switch",
                       "frames_h_rtol", "frames_nested_rtol", "frames_size_smoothing",
                       "tao_gatol", "tao_grtol", "tao_gttol")
_REALS = ("tao_fmin",)
#: Switches (``-name`` alone means true) and the values PETSc reads as one.
_BOOLS = ("frames_gn_adapt", "frames_gn_adapt_bound", "frames_active_consistent",
          "frames_hessian_safeguard")
_BOOL_VALUES = ("true", "false", "yes", "no", "on", "off", "1", "0")


def _registered(kind: str, name: str) -> bool:
    """Whether PETSc has a ``kind`` (``ksp``, ``pc``, ``ls``) type called ``name``."""
    init_petsc()
    from petsc4py import PETSc

    make = {"ksp": PETSc.KSP, "pc": PETSc.PC, "ls": PETSc.TAOLineSearch}[kind]
    obj = make().create(PETSc.COMM_SELF)
    try:
        obj.setType(name)
    except PETSc.Error:
        return False
    finally:
        obj.destroy()
    return True


def petsc_option_problem(options) -> str | None:
    """What is wrong with the PETSc ``options`` (``(name, value)`` pairs or a dict, no
    dash; the last value of a name counts), or None. Needs PETSc (started if it is not).

    ``-tao_type`` must be one of :data:`TAO_TYPES`; ``-*ksp_type``, ``-*pc_type`` and
    ``-*ls_type`` types PETSc has; ``-tao_max_it`` a positive integer;
    ``-frames_active_rounds`` and ``-frames_hessian_inertia_shifts`` integers >= 0;
    ``-frames_hessian`` one of :data:`HESSIANS`; ``-frames_size_hessian`` one of
    :data:`SIZE_HESSIANS`; dampings, tolerances and ``-frames_size_smoothing`` (the sized
    energy's smoothing weight, ``fem.problem.size_term``) finite numbers >= 0; switches
    (``-frames_gn_adapt``, ``-frames_active_consistent``, ...) true or false.
    """
    values = dict(options.items() if isinstance(options, dict) else options)
    for name, value in values.items():
        name = str(name).lstrip("-")
        if name in _BOOLS:
            if value is not None and str(value).strip().lower() not in ("", *_BOOL_VALUES):
                return f"-{name} must be true or false, got {value!r}"
            continue
        typed = _TYPE_SUFFIX.fullmatch(name)
        checked = typed is not None or name in (
            "tao_type", "frames_hessian", "frames_size_hessian", *_INTS,
            *_NON_NEGATIVE_REALS, *_REALS)
        if not checked:
            continue
        if value is None or str(value).strip() == "":
            return f"-{name} needs a value"
        value = str(value).strip()
        if name == "tao_type":
            if value not in TAO_TYPES:
                return f"unsupported -tao_type {value!r}: use one of {', '.join(TAO_TYPES)}"
        elif name == "frames_size_hessian":
            if value not in SIZE_HESSIANS:
                return (f"-frames_size_hessian must be one of {', '.join(SIZE_HESSIANS)}, "
                        f"got {value!r}")
        elif name == "frames_hessian":
            if value not in HESSIANS:
                return f"-frames_hessian must be one of {', '.join(HESSIANS)}, got {value!r}"
        elif name in _INTS:
            least = _INTS[name]
            kind = "a positive integer" if least == 1 else f"an integer >= {least}"
            try:
                number = int(value)
            except ValueError:
                return f"-{name} must be {kind}, got {value!r}"
            if not least <= number <= MAX_INT:
                return f"-{name} must be {kind} at most {MAX_INT}, got {value!r}"
        elif name in _NON_NEGATIVE_REALS or name in _REALS:
            try:
                number = float(value)
            except ValueError:
                number = math.nan
            if not math.isfinite(number) or (name in _NON_NEGATIVE_REALS and number < 0):
                sign = " >= 0" if name in _NON_NEGATIVE_REALS else ""
                return f"-{name} must be a finite number{sign}, got {value!r}"
        else:
            kind = typed.group(1)
            if not _registered(kind, value):
                what = {"ksp": "KSP", "pc": "PC", "ls": "TAO line search"}[kind]
                return f"-{name}: PETSc has no {what} type {value!r}"
    return None
