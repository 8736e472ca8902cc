"""A server's URL with credentials or a query is refused however the backend is named, and
the refusal does not show them: whatever the URL holds would be written into run configs,
episode logs, Table II labels, run folder names and messages (a security audit found
the password and an ``?api-key=`` in all of those)."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from skyvln_eval.errors import ConfigError
from skyvln_eval.harness import load_run_config
from skyvln_eval.harness.plan import load_plan
from skyvln_eval.llm.backends_file import BackendsFile, environment_backends, load_backends_file
from skyvln_eval.llm.redact import redacted_url

PASSWORD = "hunter2-pw-9e8d"
QUERY_KEY = "sk-query-7c6b"
#: Servers whose URL holds a secret, and what the refusal says it holds.
SECRET_URLS = {
    f"http://user:{PASSWORD}@127.0.0.1:8799/v1": "credentials (user:password@)",
    f"http://{PASSWORD}@127.0.0.1:8799/v1": "credentials (user:password@)",
    f"http://user:{PASSWORD}/x@127.0.0.1:8799/v1": "credentials (user:password@)",
    f"http://127.0.0.1:8799/v1?api-key={QUERY_KEY}": "a query string",
    f"https://example.org/v1#{QUERY_KEY}": "a fragment",
}


def _assert_refusal_hides_secrets(text: str, held: str) -> None:
    assert f"has {held} in it" in text, text
    assert PASSWORD not in text and QUERY_KEY not in text, text
    if held.startswith("credentials"):
        assert "api_key_env" in text  # where the key comes from instead
    if held == "a query string":
        assert "query parameters are not supported" in text and "extra_body" in text


def test_redacted_url_hides_credentials_query_and_fragment_and_never_fails() -> None:
    assert redacted_url(f"http://u:{PASSWORD}@h:1/v1?k={QUERY_KEY}#f") == (
        "http://[credentials]@h:1/v1?[query]#[fragment]"
    )
    assert redacted_url("http://127.0.0.1:8080/v1") == "http://127.0.0.1:8080/v1"
    # A '/' in the password does not end the credentials; a malformed URL is shown too.
    assert redacted_url(f"http://u:{PASSWORD}/x@h/v1") == "http://[credentials]@h/v1"
    assert redacted_url(f"http://u:{PASSWORD}@[::1/v1") == "http://[credentials]@[::1/v1"


@pytest.mark.parametrize(("url", "held"), SECRET_URLS.items())
def test_a_run_configs_base_url_and_spec_are_refused(url: str, held: str, tmp_path: Path) -> None:
    for llm in (
        {"backend": "openai:m", "base_url": url},
        {"backend": f"openai:m@{url}"},
        {"backend": f"replay:openai:m@{url}", "cache_path": "llm-cache.sqlite"},
    ):
        path = tmp_path / "run.yaml"
        config = {"system": "s", "data": "sample", "agent": {"name": "skyvln", "llm": llm}}
        path.write_text(yaml.safe_dump(config))
        with pytest.raises(ConfigError) as refused:
            load_run_config(path)
        _assert_refusal_hides_secrets(str(refused.value), held)


@pytest.mark.parametrize(("url", "held"), SECRET_URLS.items())
def test_a_backends_file_and_the_environment_refuse_them(
    url: str, held: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = tmp_path / "backends.yaml"
    for entry in ({"backend": "openai:m", "base_url": url}, {"backend": f"openai:m@{url}"}):
        file = {"format": "skyvln-eval/llm-backends", "version": 1, "backends": {"b": entry}}
        path.write_text(yaml.safe_dump(file))
        with pytest.raises(ConfigError) as refused:
            load_backends_file(path)
        _assert_refusal_hides_secrets(str(refused.value), held)
    # The form of $SKYVLN_EVAL_BACKENDS: its label was the Table II row's and a folder name.
    monkeypatch.setenv("SKYVLN_TEST_BACKENDS", f"openai:m@{url}")
    with pytest.raises(ConfigError) as refused:
        environment_backends("SKYVLN_TEST_BACKENDS", BackendsFile())
    _assert_refusal_hides_secrets(str(refused.value), held)


def test_an_entry_that_is_no_spec_is_named_redacted(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("SKYVLN_TEST_BACKENDS", f"http://u:{PASSWORD}@127.0.0.1:8799/v1")
    with pytest.raises(ConfigError) as refused:
        environment_backends("SKYVLN_TEST_BACKENDS", BackendsFile())
    assert "'http://[credentials]@127.0.0.1:8799/v1' is not 'openai:<model>'" in str(refused.value)
    # A server without its scheme, with credentials, refused as such, with or without a
    # port or path (without, it was read as a model id, the password sent to OpenAI's
    # server as part of the model's name).
    for server in ("127.0.0.1:8799/v1", "host.example.com"):
        monkeypatch.setenv("SKYVLN_TEST_BACKENDS", f"openai:m@u:{PASSWORD}@{server}")
        with pytest.raises(ConfigError) as refused:
            environment_backends("SKYVLN_TEST_BACKENDS", BackendsFile())
        _assert_refusal_hides_secrets(str(refused.value), "credentials (user:password@)")
        assert f"'openai:m@[credentials]@{server}'" in str(refused.value)


@pytest.mark.parametrize(("url", "held"), SECRET_URLS.items())
def test_a_plans_table_ii_backend_is_refused(url: str, held: str, tmp_path: Path) -> None:
    full = {"label": "Full", "mode": "official", "agent": {"name": "skyvln"}}
    backend = {"label": "local", "llm": {"backend": "openai:m", "base_url": url}}
    plan = {
        "table1": {"splits": ["val_unseen"], "systems": [full]},
        "table2": {"system": full, "backends": [backend]},
    }
    path = tmp_path / "plan.yaml"
    path.write_text(yaml.safe_dump(plan))
    with pytest.raises(ConfigError) as refused:
        load_plan(path)
    assert "table2.backends.0.llm.base_url" in str(refused.value)
    _assert_refusal_hides_secrets(str(refused.value), held)


def test_a_model_id_with_an_at_sign_keeps_its_server() -> None:
    # The server starts at the '@' before its scheme, not at the last '@' (which split a
    # server with credentials inside them, and showed the password in the error).
    from skyvln_eval.llm import LLMConfig

    config = LLMConfig(backend="openai:model@2024@http://127.0.0.1:8080/v1")
    assert (config.backend, config.base_url) == ("openai:model@2024", "http://127.0.0.1:8080/v1")
