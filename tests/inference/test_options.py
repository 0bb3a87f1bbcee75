"""How the networks run (imls_lightning.inference.options): the options node validated, torch.compile where it can
build kernels, reduced precision where it is measured faster."""
from __future__ import annotations

import pytest
import torch

from imls_lightning.base.errors import InputError
from imls_lightning.inference import options
from imls_lightning.inference.options import NetOptions, compile_available


def test_net_options_from_config_smoke_and_device_override(monkeypatch):
    monkeypatch.setattr(options, "compile_available", lambda device: None)
    assert NetOptions.from_config(None) == NetOptions()
    assert NetOptions.from_config({"half": True, "device": "cpu"}) == NetOptions(device="cpu", half=True)
    # the adaptive CLI keeps its top-level device key: it wins over the node's
    assert NetOptions.from_config({"device": "auto", "compile": True}, device="cpu") == NetOptions(device="cpu", compile=True)


def test_net_options_compile_auto_compiles_where_a_compiler_is(monkeypatch):
    """``compile: auto`` (what make bench-paper evaluates with): torch.compile where it can build kernels, else eager;
    ``compile: true`` where it cannot is a one-line error that says why and what to set instead."""
    monkeypatch.setattr(options, "compile_available", lambda device: None)
    assert NetOptions.from_config({"compile": "auto"}, device="cpu").compile is True
    monkeypatch.setattr(options, "compile_available", lambda device: "no C++ compiler")
    assert NetOptions.from_config({"compile": "auto"}, device="cpu").compile is False
    assert NetOptions.from_config({"compile": False}, device="cpu").compile is False
    with pytest.raises(InputError, match=r"^evaluate\.compile=true: torch.compile cannot run here \(no C\+\+ compiler\); "
                                         r"set compile=auto .* or false$"):
        NetOptions.from_config({"compile": True}, device="cpu", key="evaluate")


def test_compile_available_looks_for_the_compiler_torch_would_use(monkeypatch):
    found = {"g++"}
    monkeypatch.setattr("shutil.which", lambda name: f"/usr/bin/{name}" if name in found else None)
    monkeypatch.delenv("CXX", raising=False)
    assert compile_available(torch.device("cpu")) is None
    found.clear()
    assert "no C++ compiler" in compile_available(torch.device("cpu"))
    monkeypatch.setenv("CXX", "my-clang")  # $CXX, when set, is the one torch uses
    assert "no C++ compiler" in compile_available(torch.device("cpu"))
    found.add("my-clang")
    assert compile_available(torch.device("cpu")) is None


@pytest.mark.parametrize("node, needle", [({"fast": True}, r"options\.fast: unknown option"),
                                          ({"half": "yes"}, r"options\.half=yes: expected true or false"),
                                          ({"channels_last": 1}, r"options\.channels_last=1: expected true or false"),
                                          ({"compile": "yes"}, r"options\.compile=yes: expected true or false or auto")])
def test_exception_net_options_from_config_names_the_key(node, needle):
    with pytest.raises(InputError, match=needle):
        NetOptions.from_config(node)


def test_exception_net_options_from_config_missing_cuda(monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    with pytest.raises(InputError, match="device=cuda: CUDA is not available"):
        NetOptions.from_config({"device": "cuda"})


def test_half_auto_is_measured_once_and_resolves_to_a_bool(monkeypatch):
    monkeypatch.setattr(options, "_HALF_IS_FASTER", {})
    opts = NetOptions.from_config({"half": "auto"}, device="cpu")
    assert isinstance(opts.half, bool) and opts.half == options.half_is_faster(torch.device("cpu"))
    assert list(options._HALF_IS_FASTER) == ["cpu"]
    with pytest.raises(InputError, match="options.half=maybe: expected true or false or auto"):
        NetOptions.from_config({"half": "maybe"})
