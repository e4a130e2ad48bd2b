"""Prometheus metrics of the render service (``GET /metrics``), through ``prometheus-client``.

Two kinds of values:

* What the job store knows (jobs per state, attempts, workers, samples, and the histograms of
  finished jobs' render time and peak memory) is read from SQLite at scrape time by a custom
  collector: the store is the only record of job state, shared by the server and every worker
  process, so nothing has to be aggregated in this process, and the histograms (kept in the
  store's ``histograms`` table, added to in the transaction that ends a job) survive restarts
  and deletions.
* What only this process sees (HTTP responses) is a client-side ``Counter``.

Metric names are stable: dashboards and alerts rely on them (service/README.md lists them).
"""

from __future__ import annotations

import time

from prometheus_client import CollectorRegistry, Counter
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, HistogramMetricFamily
from prometheus_client.exposition import CONTENT_TYPE_PLAIN_0_0_4, generate_latest
from prometheus_client.utils import floatToGoString

from .store import HISTOGRAMS, KINDS, STATES, JobStore

__all__ = ["Metrics"]

# store histogram name -> (exposed name, help)
_HISTOGRAMS = {
    "render_seconds": ("illum_job_render_seconds",
                       "Render seconds (summed over attempts) of succeeded jobs, by job kind."),
    "peak_memory_bytes": ("illum_job_peak_memory_bytes",
                          "Peak resident memory of a job's worker over a run that ended (succeeded, failed or "
                          "canceled while running), by job kind."),
}


class _StoreCollector:
    """Reads the store at each scrape (prometheus_client calls ``collect``)."""

    def __init__(self, store: JobStore, backend: str, started: float):
        self.store = store
        self.backend = backend
        self.started = started

    def collect(self):
        c = self.store.counts()
        workers = self.store.workers()
        jobs = GaugeMetricFamily("illum_jobs", "Jobs by state (deleted jobs excluded).", labels=["state"])
        for s in STATES:
            jobs.add_metric([s], c["states"][s])
        yield jobs
        yield CounterMetricFamily("illum_jobs_created", "Jobs ever created.", value=c["created_total"])
        yield CounterMetricFamily("illum_job_attempts", "Attempts started over all stored jobs.",
                                  value=c["attempts_total"])
        yield GaugeMetricFamily("illum_samples_per_second", "Camera samples per second over running jobs.",
                                value=c["samples_per_second"])
        yield CounterMetricFamily("illum_samples_succeeded", "Samples per pixel delivered by succeeded jobs.",
                                  value=c["spp_succeeded_total"])
        w = GaugeMetricFamily("illum_workers", "Registered workers.", labels=["backend"])
        w.add_metric([self.backend], len(workers))
        yield w
        yield GaugeMetricFamily("illum_workers_busy", "Workers holding a job.",
                                value=sum(1 for r in workers if r["job_id"]))
        yield GaugeMetricFamily("illum_uptime_seconds", "Seconds since the server started.",
                                value=time.time() - self.started)
        hist = self.store.histograms()
        for key, (name, help_) in _HISTOGRAMS.items():
            fam = HistogramMetricFamily(name, help_, labels=["kind"])
            for kind in KINDS:
                buckets, total = hist.get((key, kind), (None, 0.0))
                if buckets is None:  # no observation yet: every bucket at 0
                    buckets = [(le, 0) for le in (*HISTOGRAMS[key], float("inf"))]
                fam.add_metric([kind], [(floatToGoString(le), n) for le, n in buckets], sum_value=total)
            yield fam


class Metrics:
    """The server's metrics registry: one per application (tests build several)."""

    def __init__(self, store: JobStore, backend: str, started: float):
        self.registry = CollectorRegistry(auto_describe=False)
        self.registry.register(_StoreCollector(store, backend, started))
        self.http = Counter("illum_http_requests", "HTTP responses by method and status.", ["method", "code"],
                            registry=self.registry)

    def count_request(self, method: str, status: int) -> None:
        self.http.labels(method=method, code=str(status)).inc()

    def exposition(self) -> tuple[bytes, str]:
        """(body, content type) in the text format 0.0.4, which every Prometheus scrapes."""
        return generate_latest(self.registry), CONTENT_TYPE_PLAIN_0_0_4
