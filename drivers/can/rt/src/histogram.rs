//! Latency histograms for the loop's stages (gateway/latency.py's Histogram, same bins and the
//! same summary): a sample is one division and one increment; percentiles are read when the
//! health asks, not per cycle.

/// Durations in seconds, binned; `summary` gives n, p50, p99, p99.9 and max in µs.
pub struct Histogram {
    bin_s: f64,
    counts: Vec<u64>,
    pub n: u64,
    pub max_s: f64,
}

impl Default for Histogram {
    fn default() -> Self {
        Histogram::new(5e-6, 0.02)
    }
}

impl Histogram {
    /// `bin_s` wide bins up to `span_s`, then one overflow bin [s].
    pub fn new(bin_s: f64, span_s: f64) -> Histogram {
        let bins = (span_s / bin_s).round() as usize;
        Histogram {
            bin_s,
            counts: vec![0; bins + 1],
            n: 0,
            max_s: 0.0,
        }
    }

    pub fn add(&mut self, duration_s: f64) {
        if !(duration_s >= 0.0) {
            return; // negative (clock skew between stamps) or NaN: not a sample
        }
        let bins = self.counts.len() - 1;
        let k = ((duration_s / self.bin_s) as usize).min(bins);
        self.counts[k] += 1;
        self.n += 1;
        if duration_s > self.max_s {
            self.max_s = duration_s;
        }
    }

    /// The `p`-th percentile [s] (upper edge of its bin), None without samples.
    pub fn percentile_s(&self, p: f64) -> Option<f64> {
        if self.n == 0 {
            return None;
        }
        let rank = ((p / 100.0 * self.n as f64).ceil() as u64).max(1);
        let bins = self.counts.len() - 1;
        let mut total = 0u64;
        for (k, c) in self.counts.iter().enumerate() {
            total += c;
            if total >= rank {
                if k >= bins {
                    return Some(self.max_s);
                }
                return Some(((k + 1) as f64 * self.bin_s).min(self.max_s));
            }
        }
        Some(self.max_s)
    }

    pub fn summary(&self) -> serde_json::Value {
        let us = |v: Option<f64>| match v {
            None => serde_json::Value::Null,
            Some(s) => serde_json::json!((s * 1e7).round() / 10.0),
        };
        serde_json::json!({
            "n": self.n,
            "p50_us": us(self.percentile_s(50.0)),
            "p99_us": us(self.percentile_s(99.0)),
            "p999_us": us(self.percentile_s(99.9)),
            "max_us": us(if self.n > 0 { Some(self.max_s) } else { None }),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentiles_are_upper_bin_edges_capped_by_the_max() {
        let mut h = Histogram::default();
        assert!(h.percentile_s(50.0).is_none());
        for k in 0..100 {
            h.add(k as f64 * 1e-5);
        }
        h.add(f64::NAN);
        h.add(-1.0);
        assert_eq!(h.n, 100);
        // as gateway/latency.py: Histogram() fed the same gives 0.000495, 0.00099, then 0.5
        assert!((h.percentile_s(50.0).unwrap() - 495e-6).abs() < 1e-12);
        assert!((h.percentile_s(100.0).unwrap() - 990e-6).abs() < 1e-12);
        h.add(0.5); // overflow bin
        assert_eq!(h.percentile_s(100.0).unwrap(), 0.5);
        let s = h.summary();
        assert_eq!(s["n"], 101);
        assert_eq!(s["p50_us"], 505.0);
        assert_eq!(s["p99_us"], 990.0);
        assert_eq!(s["max_us"], 500000.0);
    }
}
