//! Decoding in Web Workers: a pool of workers (`worker.js`), each instantiating this same wasm
//! module, and the refiner's spawner that sends them its decode jobs as bytes.
//!
//! The page's wasm has no threads and shares no memory with workers, so a job crosses a
//! `postMessage`: [`Portable::encode`] on the page, [`decode_job`] in a worker (a
//! [`WorkerDecoder`] set up once per worker by [`init_worker`] from the repository head's
//! bytes), and [`Portable::receive`] on the page puts the results into the refiner's channel,
//! from which the next frame applies them within its budget. The messages' buffers are
//! transferred, not copied.
//!
//! If no worker can be started (the page's scripts may not start workers, `worker.js` is
//! missing, the module fails in a worker), or a worker fails, its jobs run on the page instead
//! (the core's `Inline` behaviour) and the status says so (`workers.state`, the overlay).

use std::cell::{Cell, RefCell};
use std::collections::HashMap;
use std::rc::{Rc, Weak};

use cbdam_client::refine::WorkerDecoder;
use cbdam_client::spawn::{Portable, Spawner};
use cbdam_codec::CodecError;
use js_sys::{Array, Object, Reflect, Uint8Array};
use wasm_bindgen::closure::Closure;
use wasm_bindgen::prelude::wasm_bindgen;
use wasm_bindgen::{JsCast, JsError, JsValue};
use web_sys::{ErrorEvent, MessageEvent, Worker, WorkerOptions, WorkerType};

/// Most workers: beyond four, decoding outruns what the page's frame can apply and fetch.
const MAX_WORKERS: usize = 4;
/// Jobs the refiner may keep in flight per worker, as if each worker were this many threads:
/// answers come back only at the next frame (a frame never waits), and a worker runs its queue
/// in order, so a frame hands over what the workers can do until the next one rather than one
/// job each (on a slow page, frames are hundreds of milliseconds apart).
const JOBS_PER_WORKER: usize = 8;

thread_local! {
    /// In a worker: the decoder its context message set up.
    static WORKER: RefCell<Option<WorkerDecoder>> = const { RefCell::new(None) };
}

/// In a worker (`worker.js`): sets up the decoder from the page's context message
/// (`Refiner::worker_context`). Fails with the reason if the message is malformed.
#[wasm_bindgen]
pub fn init_worker(context: &[u8]) -> Result<(), JsError> {
    let decoder = WorkerDecoder::new(context).map_err(|e| JsError::new(&e.to_string()))?;
    WORKER.with_borrow_mut(|w| *w = Some(decoder));
    Ok(())
}

/// In a worker (`worker.js`): runs one job message and returns its results message. Fails if
/// the worker is not set up or the message is malformed (the page then decodes the job itself).
#[wasm_bindgen]
pub fn decode_job(job: &[u8]) -> Result<Vec<u8>, JsError> {
    WORKER.with_borrow(|w| {
        let decoder = w
            .as_ref()
            .ok_or_else(|| JsError::new("the worker has no decode context"))?;
        decoder.run(job).map_err(|e| JsError::new(&e.to_string()))
    })
}

/// How many workers a page starts: one core is the page's, at least one worker, at most
/// [`MAX_WORKERS`].
pub fn worker_count() -> usize {
    let cores = web_sys::window().map_or(1.0, |w| w.navigator().hardware_concurrency());
    (cores as usize).saturating_sub(1).clamp(1, MAX_WORKERS)
}

/// A job waiting for its worker's answer, with its type erased.
trait Waiting {
    fn receive(&self, answer: &[u8]) -> Result<(), CodecError>;
    fn run_here(self: Box<Self>);
    fn steps(&self) -> usize;
}

impl<J: Portable> Waiting for J {
    fn receive(&self, answer: &[u8]) -> Result<(), CodecError> {
        Portable::receive(self, answer)
    }
    fn run_here(self: Box<Self>) {
        Portable::run(*self)
    }
    fn steps(&self) -> usize {
        Portable::steps(self)
    }
}

/// A job posted to a worker: the worker's index and the job.
type Posted = (usize, Box<dyn Waiting>);

struct Slot {
    worker: Worker,
    alive: bool,
    in_flight: usize,
    _on_message: Closure<dyn FnMut(MessageEvent)>,
    _on_error: Closure<dyn FnMut(ErrorEvent)>,
}

#[derive(Default)]
struct Pool {
    slots: RefCell<Vec<Slot>>,
    /// Jobs posted and not answered, by message id.
    waiting: RefCell<HashMap<u64, Posted>>,
    next_job: Cell<u64>,
    /// Workers that answered their context message.
    ready: Cell<usize>,
    /// Diamonds decoded in workers, and the workers' time on them, ms.
    decoded: Cell<u64>,
    busy_ms: Cell<f64>,
    /// Diamonds decoded on the page (no worker, or a worker failed).
    on_page: Cell<u64>,
    /// Why workers are not (all) in use.
    problem: RefCell<Option<String>>,
    /// Called after a worker's answer went into the refiner's channel.
    on_answer: RefCell<Option<Rc<dyn Fn()>>>,
}

/// Counters of a [`WorkerPool`] for the page's status.
#[derive(Clone, Debug, Default)]
pub struct PoolStatus {
    /// Workers started and not failed.
    pub count: usize,
    /// Workers ready (set up from the context message).
    pub ready: usize,
    /// Diamonds decoded in workers.
    pub decoded: u64,
    /// Worker time spent on them, ms.
    pub busy_ms: f64,
    /// Diamonds decoded on the page instead.
    pub on_page: u64,
    /// Why decoding (partly) runs on the page, if it does.
    pub problem: Option<String>,
}

/// The refiner's spawner on a page: decode jobs go to Web Workers as bytes; closures, and jobs
/// when no worker is available, run on the page.
#[derive(Clone, Default)]
pub struct WorkerPool {
    pool: Rc<Pool>,
}

impl WorkerPool {
    /// A pool with no workers yet (jobs run on the page until [`WorkerPool::start`]).
    pub fn new() -> Self {
        Self::default()
    }

    /// Starts `count` module workers from `script` (the URL of `worker.js`), each loading the
    /// module `module` (`cbdam_web` or `cbdam_web_gl`, next to the script) and set up by
    /// `context`. Failures are reported in [`WorkerPool::status`]; jobs then run on the page.
    pub fn start(&self, script: &str, module: &str, context: &[u8], count: usize) {
        let options = WorkerOptions::new();
        options.set_type(WorkerType::Module);
        for index in 0..count {
            let worker = match Worker::new_with_options(script, &options) {
                Ok(w) => w,
                Err(e) => {
                    self.fail(format!("cannot start a Web Worker: {}", describe(&e)));
                    break;
                }
            };
            let weak = Rc::downgrade(&self.pool);
            let on_message = Closure::<dyn FnMut(MessageEvent)>::new(move |e: MessageEvent| {
                if let Some(pool) = Weak::upgrade(&weak) {
                    WorkerPool { pool }.on_message(index, &e.data());
                }
            });
            let weak = Rc::downgrade(&self.pool);
            let on_error = Closure::<dyn FnMut(ErrorEvent)>::new(move |e: ErrorEvent| {
                if let Some(pool) = Weak::upgrade(&weak) {
                    let message = format!("a decode worker failed: {}", e.message());
                    WorkerPool { pool }.worker_failed(index, message);
                }
            });
            worker.set_onmessage(Some(on_message.as_ref().unchecked_ref()));
            worker.set_onerror(Some(on_error.as_ref().unchecked_ref()));
            let init = Object::new();
            let _ = Reflect::set(&init, &"kind".into(), &"init".into());
            let _ = Reflect::set(&init, &"module".into(), &module.into());
            let bytes = Uint8Array::from(context);
            let _ = Reflect::set(&init, &"context".into(), &bytes);
            let transfer = Array::of1(&bytes.buffer());
            if let Err(e) = worker.post_message_with_transfer(&init, &transfer) {
                self.fail(format!("cannot set up a Web Worker: {}", describe(&e)));
                worker.terminate();
                break;
            }
            self.pool.slots.borrow_mut().push(Slot {
                worker,
                alive: true,
                in_flight: 0,
                _on_message: on_message,
                _on_error: on_error,
            });
        }
    }

    /// Calls `f` after each worker's answer has gone into the refiner's channel (the page then
    /// applies it at once rather than at the next animation frame).
    pub fn on_answer(&self, f: Rc<dyn Fn()>) {
        *self.pool.on_answer.borrow_mut() = Some(f);
    }

    /// The counters.
    pub fn status(&self) -> PoolStatus {
        let p = &self.pool;
        PoolStatus {
            count: self.alive(),
            ready: p.ready.get(),
            decoded: p.decoded.get(),
            busy_ms: p.busy_ms.get(),
            on_page: p.on_page.get(),
            problem: p.problem.borrow().clone(),
        }
    }

    fn alive(&self) -> usize {
        self.pool.slots.borrow().iter().filter(|s| s.alive).count()
    }

    fn fail(&self, message: String) {
        web_sys::console::warn_1(&format!("cbdam: {message}; decoding on the page").into());
        self.pool.problem.borrow_mut().get_or_insert(message);
    }

    /// Runs a job on the page, counting it.
    fn run_here(&self, job: Box<dyn Waiting>) {
        self.pool
            .on_page
            .set(self.pool.on_page.get() + job.steps() as u64);
        job.run_here();
    }

    fn on_message(&self, index: usize, data: &JsValue) {
        let get = |k: &str| Reflect::get(data, &k.into()).unwrap_or(JsValue::UNDEFINED);
        match get("kind").as_string().as_deref() {
            Some("ready") => self.pool.ready.set(self.pool.ready.get() + 1),
            Some("failed") => {
                let why = get("error").as_string().unwrap_or_default();
                self.worker_failed(index, format!("a decode worker could not start: {why}"));
            }
            Some("done") | Some("error") => {
                let id = get("id").as_f64().unwrap_or(-1.0) as u64;
                let Some((_, job)) = self.pool.waiting.borrow_mut().remove(&id) else {
                    return;
                };
                if let Some(slot) = self.pool.slots.borrow_mut().get_mut(index) {
                    slot.in_flight = slot.in_flight.saturating_sub(1);
                }
                let answer = get("bytes").dyn_into::<Uint8Array>().ok();
                let result = match answer {
                    Some(bytes) => job.receive(&bytes.to_vec()),
                    None => Err(CodecError::invalid(
                        get("error").as_string().unwrap_or_default(),
                    )),
                };
                match result {
                    Ok(()) => {
                        let p = &self.pool;
                        p.decoded.set(p.decoded.get() + job.steps() as u64);
                        p.busy_ms
                            .set(p.busy_ms.get() + get("ms").as_f64().unwrap_or(0.0));
                        let hook = p.on_answer.borrow().clone();
                        if let Some(hook) = hook {
                            hook();
                        }
                    }
                    Err(e) => {
                        self.fail(format!("a decode worker's job failed: {e}"));
                        self.run_here(job);
                    }
                }
            }
            _ => {}
        }
    }

    /// Retires worker `index`: its unanswered jobs run on the page.
    fn worker_failed(&self, index: usize, message: String) {
        self.fail(message);
        if let Some(slot) = self.pool.slots.borrow_mut().get_mut(index) {
            slot.alive = false;
            slot.in_flight = 0;
            slot.worker.terminate();
        }
        let orphans: Vec<u64> = self
            .pool
            .waiting
            .borrow()
            .iter()
            .filter(|(_, (w, _))| *w == index)
            .map(|(&id, _)| id)
            .collect();
        for id in orphans {
            let job = self.pool.waiting.borrow_mut().remove(&id);
            if let Some((_, job)) = job {
                self.run_here(job);
            }
        }
    }
}

impl Spawner for WorkerPool {
    fn sends_jobs_as_messages(&self) -> bool {
        true
    }
    fn spawn<F: FnOnce() + Send + 'static>(&self, job: F) {
        job();
    }

    fn spawn_job<J: Portable>(&self, job: J) {
        // The least busy live worker.
        let target = {
            let slots = self.pool.slots.borrow();
            slots
                .iter()
                .enumerate()
                .filter(|(_, s)| s.alive)
                .min_by_key(|(_, s)| s.in_flight)
                .map(|(i, s)| (i, s.worker.clone()))
        };
        let Some((index, worker)) = target else {
            self.run_here(Box::new(job));
            return;
        };
        let id = self.pool.next_job.get();
        self.pool.next_job.set(id + 1);
        let message = Object::new();
        let _ = Reflect::set(&message, &"kind".into(), &"job".into());
        let _ = Reflect::set(&message, &"id".into(), &JsValue::from_f64(id as f64));
        let bytes = Uint8Array::from(&job.encode()[..]);
        let _ = Reflect::set(&message, &"bytes".into(), &bytes);
        let transfer = Array::of1(&bytes.buffer());
        if let Err(e) = worker.post_message_with_transfer(&message, &transfer) {
            self.worker_failed(index, format!("cannot post a job: {}", describe(&e)));
            self.run_here(Box::new(job));
            return;
        }
        if let Some(slot) = self.pool.slots.borrow_mut().get_mut(index) {
            slot.in_flight += 1;
        }
        self.pool
            .waiting
            .borrow_mut()
            .insert(id, (index, Box::new(job)));
    }

    fn parallelism(&self) -> usize {
        match self.alive() {
            0 => 1,
            n => n * JOBS_PER_WORKER,
        }
    }

    fn runs_in_background(&self) -> bool {
        self.alive() > 0
    }
}

fn describe(e: &JsValue) -> String {
    e.as_string()
        .or_else(|| {
            e.dyn_ref::<js_sys::Error>()
                .map(|e| String::from(e.message()))
        })
        .unwrap_or_else(|| format!("{e:?}"))
}
