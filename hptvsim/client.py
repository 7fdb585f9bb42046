"""A Python client of the hptvsim service, and a Gymnasium environment that plays over it.

* :class:`Client`: one method per endpoint of ``/api/v1`` (scenarios, policies, episodes, events,
  results, interactive stepping); errors raise :class:`ServiceError` with the service's message,
  which names the offending field.
* :class:`RemoteEnv`: a ``gymnasium.Env`` whose episodes run on the service: each ``reset``
  creates an interactive episode in which this client steps one agent (over a WebSocket, or plain
  HTTP) while the service runs the other agents' policies. Stable-baselines3 trains on it
  unchanged::

      from stable_baselines3 import SAC
      from hptvsim.client import RemoteEnv

      env = RemoteEnv("http://localhost:8000", scenario="goto_tiny", agent="evader_0")
      SAC("MlpPolicy", env).learn(10_000)

The client needs ``httpx`` and ``websockets`` (the ``service`` extra) and, for
:class:`RemoteEnv`, ``gymnasium`` (the ``rl`` extra). It talks to the service only over HTTP
and WebSockets; it never imports the service.
"""

from __future__ import annotations

import json
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any, Literal

import gymnasium
import numpy as np
import numpy.typing as npt

__all__ = ["Client", "RemoteEnv", "ServiceError"]

F32 = npt.NDArray[np.float32]

FINAL_STATUSES = ("finished", "failed", "cancelled", "interrupted")


class ServiceError(RuntimeError):
    """The service answered with an error.

    Attributes:
        status: HTTP status (or the WebSocket error's status).
        detail: The service's one-line message (it names the field at fault).
        errors: Per-field errors ``[{"field", "message", "type"}]``.
    """

    def __init__(self, status: int, detail: str, errors: Sequence[Mapping[str, Any]] = ()) -> None:
        super().__init__(f"{status}: {detail}")
        self.status = status
        self.detail = detail
        self.errors = [dict(e) for e in errors]


class Client:
    """The service's REST API.

    Args:
        url: The service's base URL (``http://host:port``).
        api_key: Sent as ``X-API-Key`` when the service requires one.
        timeout: Seconds to wait for an answer.
    """

    def __init__(
        self, url: str = "http://127.0.0.1:8000", api_key: str | None = None, timeout: float = 60.0
    ) -> None:
        import httpx

        self.url = url.rstrip("/")
        self.api_key = api_key
        headers = {"X-API-Key": api_key} if api_key else {}
        self.http = httpx.Client(base_url=self.url, headers=headers, timeout=timeout)

    def close(self) -> None:
        """Close the connection pool."""
        self.http.close()

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- plumbing ------------------------------------------------------------------------------------

    def _check(self, response: Any) -> Any:
        if response.status_code >= 400:
            try:
                body = response.json()
                detail = str(body.get("detail", response.text))
                errors = body.get("errors", [])
            except ValueError:
                detail, errors = response.text, []
            raise ServiceError(response.status_code, detail, errors)
        return response

    def _get(self, path: str, **params: Any) -> Any:
        clean = {k: v for k, v in params.items() if v is not None}
        return self._check(self.http.get(f"/api/v1{path}", params=clean)).json()

    def _post(self, path: str, body: Mapping[str, Any] | None = None) -> Any:
        return self._check(self.http.post(f"/api/v1{path}", json=dict(body or {}))).json()

    # -- service -------------------------------------------------------------------------------------

    def health(self) -> dict[str, Any]:
        """``/healthz``: liveness and load."""
        data: dict[str, Any] = self._check(self.http.get("/healthz")).json()
        return data

    def config(self) -> dict[str, Any]:
        """Limits, versions and the live view's address."""
        data: dict[str, Any] = self._get("/config")
        return data

    # -- scenarios and policies ----------------------------------------------------------------------

    def scenarios(self) -> list[dict[str, Any]]:
        """The shipped scenarios (name, description, task, agents, ...)."""
        data: list[dict[str, Any]] = self._get("/scenarios")
        return data

    def scenario(self, name: str) -> dict[str, Any]:
        """A shipped scenario's tables (a starting point for an inline scenario)."""
        data: dict[str, Any] = self._get(f"/scenarios/{name}")
        return data

    def scenario_map(self, name: str) -> bytes:
        """The scenario's map as PNG bytes."""
        data: bytes = self._check(self.http.get(f"/api/v1/scenarios/{name}/map.png")).content
        return data

    def policies(self, role: Literal["pursuer", "evader"] | None = None) -> list[dict[str, Any]]:
        """Named policies (scripted and shipped trained ones), optionally for one role."""
        data: list[dict[str, Any]] = self._get("/policies", role=role)
        return data

    # -- episodes ------------------------------------------------------------------------------------

    def create_episode(
        self,
        scenario: str | Mapping[str, Any] = "source",
        *,
        mode: Literal["run", "interactive"] = "run",
        policies: Mapping[str, str] | None = None,
        control: Sequence[str] = (),
        seed: int | None = None,
        max_steps: int | None = None,
        sensor_fidelity: Literal["geometric", "signal"] | None = None,
        backend: Literal["batched", "fmu"] = "batched",
        record: bool = True,
        label: str = "",
    ) -> dict[str, Any]:
        """Create an episode (see ``POST /api/v1/episodes``); returns it as stored."""
        body: dict[str, Any] = {
            "scenario": scenario if isinstance(scenario, str) else dict(scenario),
            "mode": mode,
            "policies": dict(policies or {}),
            "control": list(control),
            "backend": backend,
            "record": record,
            "label": label,
        }
        if seed is not None:
            body["seed"] = seed
        if max_steps is not None:
            body["max_steps"] = max_steps
        if sensor_fidelity is not None:
            body["sensor_fidelity"] = sensor_fidelity
        data: dict[str, Any] = self._post("/episodes", body)
        return data

    def episode(self, episode_id: str) -> dict[str, Any]:
        """One episode."""
        data: dict[str, Any] = self._get(f"/episodes/{episode_id}")
        return data

    def episodes(
        self,
        *,
        status: Sequence[str] = (),
        scenario: str | None = None,
        mode: str | None = None,
        limit: int = 50,
        offset: int = 0,
    ) -> dict[str, Any]:
        """A page of episodes, newest first: ``{"total", "items", ...}``."""
        params: dict[str, Any] = {"scenario": scenario, "mode": mode, "limit": limit, "offset": offset}
        if status:
            params["status"] = list(status)
        data: dict[str, Any] = self._get("/episodes", **params)
        return data

    def cancel(self, episode_id: str) -> dict[str, Any]:
        """Cancel a queued or running episode."""
        data: dict[str, Any] = self._post(f"/episodes/{episode_id}/cancel")
        return data

    def delete(self, episode_id: str) -> None:
        """Delete a finished episode and its files."""
        self._check(self.http.delete(f"/api/v1/episodes/{episode_id}"))

    def events(
        self, episode_id: str | None = None, *, frames: bool = True, static: bool = False
    ) -> Iterator[dict[str, Any]]:
        """Server-sent events of one episode (or of all): ``{"event": kind, "data": {..., "episode": id}}``.

        One episode's stream ends after its final status.
        """
        path = f"/api/v1/episodes/{episode_id}/events" if episode_id else "/api/v1/events"
        params = {"frames": str(frames).lower(), "static": str(static).lower()}
        with self.http.stream("GET", path, params=params, timeout=None) as response:
            self._check(response)
            kind = "message"
            data: list[str] = []
            for line in response.iter_lines():
                if not line:
                    if data:
                        yield {"event": kind, "data": json.loads("\n".join(data))}
                    kind, data = "message", []
                elif line.startswith("event:"):
                    kind = line[6:].strip()
                elif line.startswith("data:"):
                    data.append(line[5:].lstrip())

    def wait(self, episode_id: str) -> dict[str, Any]:
        """Follow an episode's events until it ends; returns the episode."""
        for event in self.events(episode_id, frames=False):
            if event["event"] == "status" and event["data"].get("final"):
                break
        return self.episode(episode_id)

    def run(self, scenario: str | Mapping[str, Any] = "source", **kwargs: Any) -> dict[str, Any]:
        """Create a run episode and wait for its end; returns the episode."""
        created = self.create_episode(scenario, **kwargs)
        return self.wait(created["id"])

    # -- results ---------------------------------------------------------------------------------------

    def summary(self, episode_id: str) -> dict[str, Any]:
        """How the episode ended (frame schema ``EpisodeSummary``)."""
        data: dict[str, Any] = self._get(f"/episodes/{episode_id}/summary")
        return data

    def static(self, episode_id: str) -> dict[str, Any]:
        """The static part of the episode's frames (frame schema ``EpisodeStatic``)."""
        data: dict[str, Any] = self._get(f"/episodes/{episode_id}/static")
        return data

    def trajectories(self, episode_id: str) -> dict[str, Any]:
        """Every agent's trajectory (frame schema ``Trajectories``: ``step``, ``time``, ``agents``)."""
        data: dict[str, Any] = self._get(f"/episodes/{episode_id}/trajectory", format="json")
        return data

    def download_trajectory(
        self, episode_id: str, path: str | Path, *, format: Literal["csv", "parquet"] = "parquet"
    ) -> Path:
        """Save the trajectory table (one row per step and agent) as CSV or Parquet."""
        response = self._check(
            self.http.get(f"/api/v1/episodes/{episode_id}/trajectory", params={"format": format})
        )
        out = Path(path)
        out.write_bytes(response.content)
        return out

    def download_recording(self, episode_id: str, path: str | Path) -> Path:
        """Save the episode's rerun recording (``.rrd``)."""
        out = Path(path)
        with self.http.stream("GET", f"/api/v1/episodes/{episode_id}/recording") as response:
            if response.status_code >= 400:
                response.read()
                self._check(response)
            with out.open("wb") as fh:
                for chunk in response.iter_bytes():
                    fh.write(chunk)
        return out

    # -- interactive -----------------------------------------------------------------------------------

    def observe(self, episode_id: str) -> dict[str, Any]:
        """An interactive episode's agents, spaces and the controlled agents' observations."""
        data: dict[str, Any] = self._get(f"/episodes/{episode_id}/observation")
        return data

    def step(self, episode_id: str, actions: Mapping[str, Sequence[float]]) -> dict[str, Any]:
        """One step of an interactive episode with ``{agent: [v, omega]}`` of the controlled agents.

        In the 3-D game each action is ``[v, omega, w_z]`` (m/s, rad/s, m/s).
        """
        body = {"actions": {a: [float(x) for x in v] for a, v in actions.items()}}
        data: dict[str, Any] = self._post(f"/episodes/{episode_id}/step", body)
        return data

    def connect(self, episode_id: str) -> EpisodeSocket:
        """A WebSocket to an interactive episode (faster stepping than HTTP requests)."""
        return EpisodeSocket(self.url, episode_id, api_key=self.api_key)


class EpisodeSocket:
    """Steps an interactive episode over a WebSocket (``/api/v1/episodes/{id}/ws``).

    Args:
        url: The service's base URL.
        episode_id: The interactive episode.
        api_key: The service's API key, if it needs one.
    """

    def __init__(self, url: str, episode_id: str, *, api_key: str | None = None) -> None:
        from websockets.sync.client import connect

        ws_url = url.replace("https://", "wss://", 1).replace("http://", "ws://", 1)
        headers = {"X-API-Key": api_key} if api_key else None
        self.ws = connect(
            f"{ws_url}/api/v1/episodes/{episode_id}/ws", additional_headers=headers, max_size=2**24
        )

    def _call(self, message: Mapping[str, Any]) -> Any:
        self.ws.send(json.dumps(message))
        answer = json.loads(self.ws.recv())
        if answer.get("type") == "error":
            raise ServiceError(int(answer.get("status", 400)), str(answer.get("detail")))
        return answer["data"]

    def step(self, actions: Mapping[str, Sequence[float]]) -> dict[str, Any]:
        """One step with ``{agent: [v, omega]}`` (3-D game: ``[v, omega, w_z]``)."""
        data: dict[str, Any] = self._call(
            {"op": "step", "actions": {a: [float(x) for x in v] for a, v in actions.items()}}
        )
        return data

    def observe(self) -> dict[str, Any]:
        """Agents, spaces and observations."""
        data: dict[str, Any] = self._call({"op": "observe"})
        return data

    def cancel(self) -> dict[str, Any]:
        """Cancel the episode (the socket closes)."""
        data: dict[str, Any] = self._call({"op": "cancel"})
        return data

    def close(self) -> None:
        """Close the socket."""
        self.ws.close()


class RemoteEnv(gymnasium.Env[F32, F32]):
    """One agent of a game that runs on an hptvsim service, as a Gymnasium environment.

    Each ``reset`` creates an interactive episode on the service (``mode="interactive"``,
    ``control=[agent]``); ``step`` sends the agent's ``[v, omega]`` (in a 3-D scenario
    ``[v, omega, w_z]``) and the service steps every other agent with its policy. Spaces are the
    agent's (Eq. 14 observations; Eqs. 15-16 actions), read from the service. Every episode is
    stored on the service with its trajectories and, when ``record``, its recording;
    :attr:`episode_id` is the current one's id.

    Args:
        url: The service's base URL.
        scenario: A shipped scenario's name or scenario data.
        agent: The agent to control (default: the scenario's first agent).
        policies: Policies of the other agents (default: the service's defaults, hptvsim.zoo.default_policy).
        seed: Seed of the first episode; later episodes use the following seeds (``reset(seed=)``
            starts over from a given one).
        max_steps: Step limit of each episode (default: the scenario's).
        sensor_fidelity: Sonar model (default: the scenario's).
        backend: ``batched`` or ``fmu``.
        record: Whether the service writes a recording of each episode.
        transport: ``ws`` (a WebSocket per episode, fastest) or ``http``.
        api_key: The service's API key, if it needs one.
        label: Label of the episodes in the service's list.
    """

    metadata: dict[str, Any] = {"render_modes": []}  # noqa: RUF012 - Gymnasium's attribute

    def __init__(
        self,
        url: str,
        *,
        scenario: str | Mapping[str, Any] = "source",
        agent: str | None = None,
        policies: Mapping[str, str] | None = None,
        seed: int | None = None,
        max_steps: int | None = None,
        sensor_fidelity: Literal["geometric", "signal"] | None = None,
        backend: Literal["batched", "fmu"] = "batched",
        record: bool = True,
        transport: Literal["ws", "http"] = "ws",
        api_key: str | None = None,
        label: str = "RemoteEnv",
    ) -> None:
        if transport not in ("ws", "http"):
            raise ValueError(f"transport = {transport!r} is invalid; valid: 'ws', 'http'")
        self.client = Client(url, api_key=api_key)
        self.scenario = scenario
        self.policies = dict(policies or {})
        self.max_steps = max_steps
        self.sensor_fidelity = sensor_fidelity
        self.backend = backend
        self.record = record
        self.transport = transport
        self.label = label
        self._next_seed = seed if seed is not None else 0
        self._socket: EpisodeSocket | None = None
        self.episode_id: str | None = None
        self._fresh = False
        self._done = True
        if agent is None:
            if isinstance(scenario, str):
                known = {s["name"]: s for s in self.client.scenarios()}
                if scenario not in known:
                    raise ValueError(f"no shipped scenario {scenario!r}; valid: {', '.join(known)}")
                agent = str(known[scenario]["agents"][0])
            else:
                raise ValueError("give agent= when the scenario is data")
        self.agent = agent
        state = self._open(self._next_seed)
        spaces = state["spaces"]
        obs = spaces["observation"]
        act = spaces["action"][agent]
        self.observation_space = gymnasium.spaces.Box(
            np.asarray(obs["low"], dtype=np.float32),
            np.asarray(obs["high"], dtype=np.float32),
            dtype=np.float32,
        )
        self.action_space = gymnasium.spaces.Box(
            np.asarray(act["low"], dtype=np.float32),
            np.asarray(act["high"], dtype=np.float32),
            dtype=np.float32,
        )
        self._first_obs = np.asarray(state["observations"][agent], dtype=np.float32)

    def _open(self, seed: int) -> dict[str, Any]:
        """Create an interactive episode with ``seed``; returns its state."""
        self._close_episode()
        created = self.client.create_episode(
            self.scenario,
            mode="interactive",
            policies=self.policies,
            control=[self.agent],
            seed=seed,
            max_steps=self.max_steps,
            sensor_fidelity=self.sensor_fidelity,
            backend=self.backend,
            record=self.record,
            label=self.label,
        )
        self.episode_id = str(created["id"])
        self._seed_used = seed
        self._next_seed = seed + 1
        if self.transport == "ws":
            self._socket = self.client.connect(self.episode_id)
            state = self._socket.observe()
        else:
            state = self.client.observe(self.episode_id)
        self._fresh = True
        self._done = False
        return state

    def _close_episode(self) -> None:
        """Cancel the current episode if it still runs, and close its socket."""
        if self.episode_id is not None and not self._done:
            try:
                if self._socket is not None:
                    self._socket.cancel()
                else:
                    self.client.cancel(self.episode_id)
            except ServiceError as exc:
                if exc.status != 409:  # 409: it has ended meanwhile
                    raise
        if self._socket is not None:
            self._socket.close()
            self._socket = None
        self._done = True

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[F32, dict[str, Any]]:
        """Start a new episode on the service (``seed``: its seed; default: the next one)."""
        super().reset(seed=seed)
        want = seed if seed is not None else self._next_seed
        if self._fresh and not self._done and want == self._seed_used:
            obs = self._first_obs  # the episode opened in __init__ (or the last reset) is untouched
        else:
            state = self._open(want)
            obs = np.asarray(state["observations"][self.agent], dtype=np.float32)
        self._fresh = False
        return obs.copy(), {"seed": self._seed_used}

    def step(self, action: npt.ArrayLike) -> tuple[F32, float, bool, bool, dict[str, Any]]:
        """Send the agent's ``[v, omega]`` (3-D: ``[v, omega, w_z]``); returns the Gymnasium step tuple."""
        if self.episode_id is None or self._done:
            raise RuntimeError("the episode is over; call reset()")
        a = np.asarray(action, dtype=np.float64).reshape(-1)
        want = self.action_space.shape
        if a.shape != want:
            names = "[v, omega, w_z]" if want == (3,) else "[v, omega]"
            raise ValueError(f"the action must be {names} (shape {want}); got shape {a.shape}")
        actions = {self.agent: [float(x) for x in a]}
        self._fresh = False
        if self._socket is not None:
            out = self._socket.step(actions)
        else:
            out = self.client.step(self.episode_id, actions)
        terminated = bool(out["terminated"][self.agent])
        truncated = bool(out["truncated"][self.agent])
        if out["done"] or terminated or truncated:
            if out["done"]:
                self._done = True  # the service finished and stored the episode
            else:
                self._close_episode()  # the agent is done; the others would go on: end it here
        info = dict(out["infos"][self.agent])
        info["step"] = out["step"]
        return (
            np.asarray(out["observations"][self.agent], dtype=np.float32),
            float(out["rewards"][self.agent]),
            terminated,
            truncated,
            info,
        )

    def close(self) -> None:
        """Cancel a running episode and close the connections."""
        try:
            self._close_episode()
        finally:
            self.client.close()
