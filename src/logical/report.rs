//! What a traced set of rays reports: its work counters, per ray, and the pager's figures, in
//! the shape `oavm-trace --json` prints them ([`SetReport`]). What a whole run reports around
//! its sets is [`super::run`]'s.

use std::fmt;

use serde::Serialize;

use super::pager::PageCounters;
use super::trace::Counters;

/// The pager's counters with the hit rate and the bytes read per ray.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct PageReport {
    #[serde(flatten)]
    pub counters: PageCounters,
    pub hit_rate: f64,
    pub bytes_read_per_ray: f64,
}

impl PageReport {
    pub fn new(c: &Counters) -> PageReport {
        PageReport {
            counters: c.page,
            hit_rate: c.page.hits as f64 / c.page.requested.max(1) as f64,
            bytes_read_per_ray: c.page.bytes_read as f64 / c.rays.max(1) as f64,
        }
    }

    /// The figures as a clause of a line of text, `"; pager: 120 blocks asked, 3 misses (97.5
    /// % hits), 1.2 MB read (10 B/ray), peak 5.0 MB resident of 512.0 MB"`, with the scene's
    /// peak resident bytes and budget ([`super::Scene::peak_resident_bytes`],
    /// [`super::Scene::budget`]).
    pub fn clause(&self, peak_resident_bytes: u64, budget: u64) -> String {
        format!(
            "; pager: {} blocks asked, {} misses ({:.1} % hits), {:.1} MB read ({:.0} B/ray), \
             peak {:.1} MB resident of {:.1} MB",
            self.counters.requested,
            self.counters.misses,
            100.0 * self.hit_rate,
            self.counters.bytes_read as f64 / 1e6,
            self.bytes_read_per_ray,
            peak_resident_bytes as f64 / 1e6,
            budget as f64 / 1e6,
        )
    }
}

/// The figures of one set of rays traced in `seconds`.
#[derive(Clone, Debug, Serialize)]
pub struct SetReport {
    pub rays: u64,
    /// Rays that hit something (closest-hit sets).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub hits: Option<u64>,
    /// Rays occluded (any-hit sets).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub occluded: Option<u64>,
    /// Hits in all (every-hit sets: `--all-hits`, `--count-hits`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub all_hits: Option<u64>,
    pub seconds: f64,
    pub mrays_per_s: f64,
    pub nodes_visited: u64,
    pub leaves_visited: u64,
    pub volumes_crossed: u64,
    pub leaves_culled: u64,
    pub links_culled: u64,
    pub top_nodes_culled: u64,
    pub triangles_tested: u64,
    pub clusters_entered: u64,
    pub cluster_nodes_visited: u64,
    pub boxes_tested: u64,
    pub groups_tested: u64,
    /// Ropes followed (`--walk ropes`, spec §8.4; 0 elsewhere).
    pub ropes_followed: u64,
    pub nodes_visited_per_ray: f64,
    pub leaves_visited_per_ray: f64,
    pub volumes_crossed_per_ray: f64,
    pub triangles_tested_per_ray: f64,
    pub clusters_entered_per_ray: f64,
    pub cluster_nodes_visited_per_ray: f64,
    pub boxes_tested_per_ray: f64,
    pub groups_tested_per_ray: f64,
    pub ropes_followed_per_ray: f64,
    /// Streamed sets ([`super::Order::Stream`]): walks parked at a block and resumed, times a
    /// block's queue was served, and the most bytes the parked walks took at once.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub stream: Option<StreamReport>,
    pub page: PageReport,
}

/// What a stream did (see [`SetReport::stream`]).
#[derive(Clone, Copy, Debug, Serialize)]
pub struct StreamReport {
    pub walks_parked: u64,
    pub walks_parked_per_ray: f64,
    pub blocks_served: u64,
    pub peak_parked_bytes: u64,
    /// Walks answered wide as they started (every block they needed resident), never parked.
    pub walks_unparked: u64,
}

/// What a set's rays answered: how many hit (closest hit) or were occluded (any hit).
#[derive(Clone, Copy, Debug)]
pub enum Answered {
    Hits(u64),
    Occluded(u64),
    /// Every hit along each ray: how many rays hit something, and the hits in all.
    Listed(u64, u64),
    /// A total over sets of both kinds.
    Mixed,
}

impl SetReport {
    pub fn new(c: &Counters, seconds: f64, answered: Answered) -> SetReport {
        let per_ray = |x: u64| x as f64 / c.rays.max(1) as f64;
        let (hits, occluded, all_hits) = match answered {
            Answered::Hits(n) => (Some(n), None, None),
            Answered::Occluded(n) => (None, Some(n), None),
            Answered::Listed(n, all) => (Some(n), None, Some(all)),
            Answered::Mixed => (None, None, None),
        };
        SetReport {
            rays: c.rays,
            hits,
            occluded,
            all_hits,
            seconds,
            mrays_per_s: c.rays as f64 / seconds.max(1e-12) / 1e6,
            nodes_visited: c.nodes_visited,
            leaves_visited: c.leaves_visited,
            volumes_crossed: c.volumes_crossed,
            leaves_culled: c.leaves_culled,
            links_culled: c.links_culled,
            top_nodes_culled: c.top_nodes_culled,
            triangles_tested: c.triangles_tested,
            clusters_entered: c.clusters_entered,
            cluster_nodes_visited: c.cluster_nodes_visited,
            boxes_tested: c.boxes_tested,
            groups_tested: c.groups_tested,
            ropes_followed: c.ropes_followed,
            nodes_visited_per_ray: per_ray(c.nodes_visited),
            leaves_visited_per_ray: per_ray(c.leaves_visited),
            volumes_crossed_per_ray: per_ray(c.volumes_crossed),
            triangles_tested_per_ray: per_ray(c.triangles_tested),
            clusters_entered_per_ray: per_ray(c.clusters_entered),
            cluster_nodes_visited_per_ray: per_ray(c.cluster_nodes_visited),
            boxes_tested_per_ray: per_ray(c.boxes_tested),
            groups_tested_per_ray: per_ray(c.groups_tested),
            ropes_followed_per_ray: per_ray(c.ropes_followed),
            stream: (c.blocks_served > 0).then(|| StreamReport {
                walks_parked: c.walks_parked,
                walks_parked_per_ray: per_ray(c.walks_parked),
                blocks_served: c.blocks_served,
                peak_parked_bytes: c.peak_parked_bytes,
                walks_unparked: c.walks_unparked,
            }),
            page: PageReport::new(c),
        }
    }

    /// What the set's rays answered (as given to [`SetReport::new`]).
    pub fn answered(&self) -> Answered {
        match (self.hits, self.occluded) {
            (Some(n), _) if let Some(all) = self.all_hits => Answered::Listed(n, all),
            (Some(n), _) => Answered::Hits(n),
            (_, Some(n)) => Answered::Occluded(n),
            _ => Answered::Mixed,
        }
    }
}

/// `12 hits`, `3 occluded`, or `hits and occluded` for a total over both kinds.
impl fmt::Display for Answered {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Answered::Hits(n) => write!(f, "{n} hits"),
            Answered::Occluded(n) => write!(f, "{n} occluded"),
            Answered::Listed(n, all) => write!(f, "{n} hit, {all} hits in all"),
            Answered::Mixed => f.write_str("hits and occluded"),
        }
    }
}
