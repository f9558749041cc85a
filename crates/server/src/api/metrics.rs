//! Prometheus metrics (`GET /metrics`, text exposition format).

use prometheus_client::encoding::EncodeLabelSet;
use prometheus_client::metrics::counter::Counter;
use prometheus_client::metrics::family::Family;
use prometheus_client::metrics::gauge::Gauge;
use prometheus_client::metrics::histogram::{exponential_buckets, Histogram};
use prometheus_client::registry::Registry;

#[derive(Debug, Clone, Hash, PartialEq, Eq, EncodeLabelSet)]
pub struct RequestLabels {
    pub method: String,
    /// The route pattern (`/v1/models/{id}`), never the raw path, to bound the label set.
    pub route: String,
    pub status: u16,
}

/// The service's counters, histograms and gauges.
#[derive(Debug)]
pub struct Metrics {
    registry: Registry,
    pub requests: Family<RequestLabels, Counter>,
    pub extraction_seconds: Histogram,
    pub search_seconds: Histogram,
    pub models: Gauge,
    pub extraction_in_flight: Gauge,
    pub rankings_waiting: Gauge,
    pub patches_pending: Gauge,
    pub replica: ReplicaMetrics,
}

/// How a replica follows a store shared with others (`api::follow`); zero on a store of its
/// own.
#[derive(Debug, Default)]
pub struct ReplicaMetrics {
    /// The last change position applied.
    pub position: Gauge,
    /// Changes announced and not yet applied.
    pub lag: Gauge,
    /// 1 while the store answers, 0 while it cannot be reached.
    pub store_up: Gauge,
    /// Connections to the store lost and made again since the start.
    pub reconnections: Gauge,
    /// 1 once another replica adopted other extraction parameters for the store.
    pub other_extraction: Gauge,
}

impl Default for Metrics {
    fn default() -> Self {
        let requests = Family::<RequestLabels, Counter>::default();
        let extraction_seconds = Histogram::new(exponential_buckets(0.01, 2.0, 14));
        let search_seconds = Histogram::new(exponential_buckets(0.0005, 2.0, 14));
        let models = Gauge::default();
        let extraction_in_flight = Gauge::default();
        let rankings_waiting = Gauge::default();
        let patches_pending = Gauge::default();
        let mut registry = Registry::with_prefix("salient");
        registry.register(
            "http_requests",
            "HTTP requests by route and status",
            requests.clone(),
        );
        registry.register(
            "extraction_seconds",
            "Time to extract a signature",
            extraction_seconds.clone(),
        );
        registry.register(
            "search_seconds",
            "Time to rank the collection",
            search_seconds.clone(),
        );
        registry.register("models", "Models in the store", models.clone());
        registry.register(
            "extraction_in_flight",
            "Extractions running or queued",
            extraction_in_flight.clone(),
        );
        registry.register(
            "rankings_waiting",
            "Rankings waiting for their turn (config rankings)",
            rankings_waiting.clone(),
        );
        registry.register(
            "patches_pending",
            "Models whose patch descriptors (partial search) are still to be made",
            patches_pending.clone(),
        );
        let replica = ReplicaMetrics::default();
        for (name, help, gauge) in [
            (
                "replica_position",
                "The last change of the shared store this replica applied",
                &replica.position,
            ),
            (
                "replica_lag_changes",
                "Changes of the shared store announced and not yet applied here",
                &replica.lag,
            ),
            (
                "store_up",
                "1 while the shared store answers, 0 while it cannot be reached",
                &replica.store_up,
            ),
            (
                "store_reconnections",
                "Connections to the shared store lost and made again since the start",
                &replica.reconnections,
            ),
            (
                "replica_other_extraction",
                "1 once another replica adopted other extraction parameters for the shared store",
                &replica.other_extraction,
            ),
        ] {
            registry.register(name, help, gauge.clone());
        }
        Self {
            registry,
            replica,
            requests,
            extraction_seconds,
            search_seconds,
            models,
            extraction_in_flight,
            rankings_waiting,
            patches_pending,
        }
    }
}

impl Metrics {
    /// The text exposition of every metric.
    pub fn render(&self) -> String {
        let mut text = String::new();
        prometheus_client::encoding::text::encode(&mut text, &self.registry)
            .expect("writing to a String cannot fail");
        text
    }
}
