"""PETSc start-up and the one mechanism for the options database (ufl_frames.bootstrap)."""

import pytest

from ufl_frames.bootstrap import init_petsc, options_scope, petsc_defaults, petsc_initialised

init_petsc([])  # not pytest's command line

from petsc4py import PETSc  # noqa: E402


def test_options_scope_restores_the_whole_database():
    db = PETSc.Options()
    db.setValue("scope_kept", "1")
    try:
        with pytest.raises(RuntimeError, match="inside"), options_scope(
            [("scope_new", "a"), ("scope_kept", "2"), ("scope_flag", None)]
        ):
            assert db.getString("scope_new") == "a" and db.getString("scope_kept") == "2"
            assert db.hasName("scope_flag")
            db.setValue("scope_added_inside", "x")  # e.g. a solver's default
            raise RuntimeError("inside")  # restored on the error path too
        assert not db.hasName("scope_new") and not db.hasName("scope_flag")
        assert not db.hasName("scope_added_inside")
        assert db.getString("scope_kept") == "1"
    finally:
        db.delValue("scope_kept")


def test_defaults_inside_a_scope_do_not_override_the_user():
    with options_scope([("scoped_tao_max_it", "7")]):
        with petsc_defaults("scoped_", {"tao_max_it": 100, "tao_gttol": 1e-3}) as opts:
            assert opts.getInt("tao_max_it") == 7  # the user's value wins
            assert opts.getReal("tao_gttol") == 1e-3
        assert not PETSc.Options("scoped_").hasName("tao_gttol")
    assert not PETSc.Options().hasName("scoped_tao_max_it")


def test_late_options_are_not_dropped_silently():
    assert petsc_initialised()
    with pytest.warns(RuntimeWarning, match="already initialised.*-tao_monitor"):
        init_petsc(["prog", "-tao_monitor"])
    assert not PETSc.Options().hasName("tao_monitor")
