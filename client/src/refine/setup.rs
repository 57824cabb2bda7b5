//! Setting a refiner up: the boxes and errors of the stored diamonds saturated over their
//! descendants, the roots decoded from the head, the coarsest cut.

use super::drawn::DrawnList;
use super::job::root_colour;
use super::node::Info;
use super::pacing::Pacing;
use super::speculate::Ahead;
use super::state::{CutState, Requests, Residency};
use super::{LruCache, RefineConfig, Refiner};
use crate::access::DataSource;
use crate::access::Drape;
use crate::patch::{HalfPatch, packed};
use crate::spawn::Spawner;
use crate::world::{World, exaggerated};
use cbdam_codec::CodecError;
use cbdam_codec::geometry::{Cut, DiamondId, Domain, Half, IdMap, IdSet};
use cbdam_codec::hierarchy::Decoder;
use cbdam_codec::repository::index::IndexEntry;
use std::sync::Arc;

impl<S: DataSource, X: Spawner> Refiner<S, X> {
    /// A refiner with the coarsest cut (roots only), decoding on `spawner`.
    pub fn with_spawner(source: S, config: RefineConfig, spawner: X) -> Result<Self, CodecError> {
        let decoder = source.decoder()?;
        let params = *source.head().params();
        let src_finest = params.domain.finest_level();
        let shift = config.detail.map_or(0, |d| d.level_pairs);
        let world = exaggerated(
            &World::new(
                &params,
                source.head().plan(),
                source.head().georef(),
                source.head().entries(),
            ),
            config.exaggeration,
        )
        .with_detail(shift)?;
        if world.is_planet() && shift > 0 {
            return Err(CodecError::unsupported(
                "synthetic detail below the finest level is planar only",
            ));
        }
        let domain = world.domain;
        let stored = saturated_boxes(source.head().entries(), &world, shift);
        let drape = source.drape().cloned().map(Arc::new);
        let roots = root_patches(&decoder, drape.as_deref(), &domain, shift)?;
        let (done_tx, done_rx) = std::sync::mpsc::channel();
        let mut me = Self {
            source,
            spawner,
            decoder: Arc::new(decoder),
            drape,
            domain,
            world,
            shift,
            source_finest: src_finest,
            stored,
            synthetic: IdMap::default(),
            cut_state: CutState {
                cut: Cut::new(),
                nodes: IdMap::default(),
                roots,
                drawn: DrawnList::default(),
                candidates: IdMap::default(),
                leaves: IdMap::default(),
            },
            residency: Residency {
                records: LruCache::new(config.record_cache_bytes),
                decoded: LruCache::new(config.decoded_cache_bytes),
                cut_bytes: 0,
                evicted: Vec::new(),
            },
            requests: Requests::default(),
            frame: 0,
            last_camera: None,
            pacing: Pacing::new(config.budget),
            collecting: false,
            kept_heap: None,
            last_ahead: IdMap::default(),
            heap_whole: false,
            decoding: IdSet::default(),
            ahead: Ahead::default(),
            done_tx,
            done_rx,
            config,
        };
        me.cut_state.rebuild_drawn(&me.domain);
        let roots: Vec<DiamondId> = me.domain.roots().collect();
        for r in roots {
            let info = me.info(r);
            me.cut_state.candidates.insert(r, info);
        }
        Ok(me)
    }
}

/// Per stored diamond (at the detail shift's level) its [`Info`] — the box and error saturated
/// over its descendants, so a parent's bounds every child's — and its index in `entries`.
fn saturated_boxes(entries: &[IndexEntry], world: &World, shift: u32) -> IdMap<(Info, usize)> {
    let domain = world.domain;
    // Saturate boxes and errors bottom-up: ids sort coarse to fine, so go in reverse.
    let mut stored: IdMap<(Info, usize)> = IdMap::default();
    for (index, e) in entries.iter().enumerate().rev() {
        let id = e.id.finer(shift);
        let (mut lo, mut hi) = world.diamond_box(id, e.min, e.max);
        // On a planet the flat triangles' sag under the curved surface counts too.
        let mut err_m = (f64::from(e.object_error) * world.unit).max(world.chord_error(id));
        for c in domain.children(id).into_iter().flatten() {
            if let Some((ci, _)) = stored.get(&c) {
                lo = lo.min(ci.lo);
                hi = hi.max(ci.hi);
                err_m = err_m.max(ci.err_m);
            }
        }
        stored.insert(id, (Info { err_m, lo, hi }, index));
    }
    stored
}

/// The roots' half-patches, decoded from the head (and coloured from `drape`).
fn root_patches(
    decoder: &Decoder,
    drape: Option<&Drape>,
    domain: &Domain,
    shift: u32,
) -> Result<IdMap<[Arc<HalfPatch>; 2]>, CodecError> {
    let mut roots = IdMap::default();
    for r in domain.roots() {
        let src = r.coarser(shift);
        let heights = decoder.grid_of(src, [None, None]);
        let valid = decoder.validity_of(src, [None, None]);
        let colour = drape
            .map(|d| root_colour(d, src).map(|g| packed(&g)))
            .transpose()?;
        roots.insert(
            r,
            Half::BOTH.map(|half| {
                Arc::new(HalfPatch {
                    id: r,
                    half,
                    heights: heights.clone(),
                    valid: valid.clone(),
                    colour: colour.clone(),
                })
            }),
        );
    }
    Ok(roots)
}
