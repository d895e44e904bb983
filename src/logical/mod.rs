//! The logical layer (OAVM paper §2.3-2.5): the octree with merged empty volumes as the tracer
//! sees it. It owns the tracer ([`Tree`]), the pager that brings blocks in within a memory
//! budget (a cache policy), an opened file ready to trace ([`Scene`]: budget, threads, batch
//! calls in an [`Order`]), a frame of primary and shadow rays ([`Scene::trace_frame`], of a
//! [`RaySet`]), what traced rays report ([`SetReport`], [`FrameFigures`]) and the structural
//! part of full verification.

mod batch;
mod chunked;
mod frame;
mod held;
mod hits;
mod nearest;
mod order;
mod pager;
mod report;
mod run;
mod scene;
mod stream;
mod top_bounds;
mod trace;
mod verify;

pub(crate) use batch::in_order;
pub use frame::{Frame, FrameOptions, RaySet, SetStats};
pub use nearest::{ClosestPoint, VOTE_DIRECTIONS};
pub use order::{COARSE_BITS, KEY_BITS, Order, RayKeys};
pub use pager::{BlockSource, PageCounters};
pub use report::{Answered, PageReport, SetReport};
pub use run::{AnsweredSet, Answers, FrameFigures, Query, RunReport, TraceRun, Verification};
pub use scene::{
    BYTES_PER_RAY, BlockReads, FALLBACK_MEM_BUDGET, IO_THREADS_PER_CORE, Scene, SceneInfo,
    SceneOptions, default_mem_budget, max_rays, max_rays_in_memory,
};
#[cfg(feature = "group-trace")]
pub use trace::group_trace;
pub use trace::{Counters, HitInfo, Nearest, TraceError, Tree, Walk, closest_on_triangle};
pub use verify::VerifyReport;
