//! The Python package `osms`: PyO3 bindings of osms-gym (a gymnasium environment, batch evaluation with the GIL released, the store's policies as Python callables).
//!
//! This module is `osms._native`; the package's Python half (`python/osms/`) builds the
//! gymnasium environment, `osms.eval.evaluate` and `osms.policies` on it. Stepping and the
//! store's policies run here with the GIL released.

use std::path::PathBuf;
use std::sync::{Arc, Mutex, MutexGuard};

use numpy::{IntoPyArray, PyArray1, PyArray2, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2};
use osms_gym::{
    Autoreset, GymError, Native, Pool, Project, Protocol, SingleEpisode, StepInfo, VectorEpisodes,
};
use pyo3::create_exception;
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;

// Named under `osms`, where the package exports them, so a traceback reads `osms.OsmsError`.
create_exception!(
    osms,
    OsmsError,
    PyRuntimeError,
    "A project, stage, artifact or call osms cannot use; the message says which and what would do."
);
create_exception!(
    osms,
    ActionError,
    PyValueError,
    "A policy's action the world cannot run (wrong shape, not finite, outside [-1, 1]); the message names the condition and the control step."
);

fn to_py(e: GymError) -> PyErr {
    match e {
        GymError::Action { .. } => ActionError::new_err(e.to_string()),
        GymError::Argument(_) | GymError::Condition { .. } => PyValueError::new_err(e.to_string()),
        other => OsmsError::new_err(other.to_string()),
    }
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    // A panic inside a step leaves no half-updated state that a later call could misread: every
    // call checks the pool's generation and slots first.
    m.lock().unwrap_or_else(|p| p.into_inner())
}

/// A project: pipeline.toml under a profile, and its store.
#[pyclass(name = "Project", module = "osms._native", frozen)]
struct PyProject {
    inner: Arc<Project>,
}

#[pymethods]
impl PyProject {
    #[new]
    #[pyo3(signature = (pipeline=None, store=None, profile=None))]
    fn new(
        py: Python<'_>,
        pipeline: Option<PathBuf>,
        store: Option<PathBuf>,
        profile: Option<String>,
    ) -> PyResult<Self> {
        let project = py
            .detach(|| Project::open(pipeline.as_deref(), store.as_deref(), profile.as_deref()))
            .map_err(to_py)?;
        Ok(PyProject {
            inner: Arc::new(project),
        })
    }

    #[getter]
    fn profile(&self) -> String {
        self.inner.profile().to_string()
    }

    /// A project is immutable: a copy is the project itself (gymnasium deep-copies an
    /// environment's keyword arguments, `project=` among them).
    fn __copy__(slf: Py<Self>) -> Py<Self> {
        slf
    }

    fn __deepcopy__(slf: Py<Self>, _memo: &Bound<'_, PyAny>) -> Py<Self> {
        slf
    }

    /// Pickled as what opens it again (a vector environment's worker process gets its own).
    fn __reduce__<'py>(
        slf: &Bound<'py, Self>,
    ) -> PyResult<(Bound<'py, PyAny>, (PathBuf, PathBuf, String))> {
        let this = slf.get();
        Ok((
            slf.get_type().into_any(),
            (
                this.inner.pipeline_path().to_path_buf(),
                this.inner.store_path().to_path_buf(),
                this.inner.profile().to_string(),
            ),
        ))
    }

    #[getter]
    fn pipeline(&self) -> PathBuf {
        self.inner.pipeline_path().to_path_buf()
    }

    #[getter]
    fn store(&self) -> PathBuf {
        self.inner.store_path().to_path_buf()
    }

    /// The evaluation stage (protocol) of `name`: an instance of an `eval_*` or `evaluate` stage.
    fn protocol(&self, py: Python<'_>, name: &str) -> PyResult<PyProtocol> {
        let inner = self.inner.clone();
        let protocol = py.detach(|| inner.protocol(name)).map_err(to_py)?;
        Ok(PyProtocol {
            inner: Arc::new(protocol),
        })
    }

    /// The protocol osms uses by default on condition set `conditions`.
    fn default_protocol(&self, conditions: &str) -> PyResult<String> {
        self.inner.default_protocol(conditions).map_err(to_py)
    }

    /// The pipeline's evaluation stages, in order.
    fn evaluation_stages(&self) -> Vec<String> {
        self.inner.evaluation_stages()
    }

    /// The pipeline's condition sets, in order.
    fn condition_sets(&self) -> Vec<String> {
        self.inner.condition_sets()
    }

    /// A policy of the store: `scripted`, or a built `teacher` or `student` instance.
    fn policy(&self, py: Python<'_>, name: &str) -> PyResult<PyNative> {
        let inner = self.inner.clone();
        let native = py.detach(|| Native::load(&inner, name)).map_err(to_py)?;
        Ok(PyNative { inner: native })
    }
}

/// The rules of one evaluation stage's rollouts.
#[pyclass(name = "Protocol", module = "osms._native", frozen)]
struct PyProtocol {
    inner: Arc<Protocol>,
}

#[pymethods]
impl PyProtocol {
    #[getter]
    fn name(&self) -> String {
        self.inner.name.clone()
    }

    #[getter]
    fn kind(&self) -> String {
        self.inner.kind.clone()
    }

    #[getter]
    fn conditions(&self) -> String {
        self.inner.conditions_name.clone()
    }

    #[getter]
    fn n_conditions(&self) -> usize {
        self.inner.conditions.len()
    }

    #[getter]
    fn seed(&self) -> Option<u64> {
        self.inner.seed
    }

    /// Control steps per second.
    #[getter]
    fn control_hz(&self) -> f64 {
        1.0 / self.inner.world.control_period_secs()
    }

    /// The longest rollout in control steps (the success criteria's episode limit).
    #[getter]
    fn max_steps(&self) -> usize {
        max_steps(
            self.inner.rules.rollout.success.max_episode_secs,
            self.inner.world.control_period_secs(),
        )
    }

    /// The task of condition `index` as osms's LeRobot export names it ("catch the …").
    fn task(&self, index: i64) -> PyResult<String> {
        Ok(osms_export::task_name(
            self.inner.condition(index).map_err(to_py)?.variant,
        ))
    }

    fn __repr__(&self) -> String {
        format!(
            "Protocol({:?}: {} conditions of `{}`)",
            self.inner.name,
            self.inner.conditions.len(),
            self.inner.conditions_name
        )
    }
}

/// The most control steps an episode of `max_episode_secs` takes at `period` seconds a step.
fn max_steps(max_episode_secs: f64, period: f64) -> usize {
    (max_episode_secs / period).ceil() as usize + 1
}

/// A policy of the store as a Python callable over the observations of a [`PyPool`].
#[pyclass(name = "NativePolicy", module = "osms._native", frozen)]
struct PyNative {
    inner: Native,
}

#[pymethods]
impl PyNative {
    #[getter]
    fn name(&self) -> String {
        self.inner.name().to_string()
    }

    /// The actions (float64, one row per observed rollout) for a batch that a pool observed.
    fn __call__<'py>(
        &self,
        py: Python<'py>,
        observation: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let batch = observation
            .get_item("osms_batch")
            .ok()
            .and_then(|b| b.extract::<PyRef<'_, PyBatch>>().ok())
            .ok_or_else(|| {
                OsmsError::new_err(format!(
                    "`{}` acts on observations from osms (osms.eval.evaluate, or an osms pool's `observe()`): they carry the rollouts' full state under `osms_batch`",
                    self.inner.name()
                ))
            })?;
        let (pool, generation, slots) = (batch.pool.clone(), batch.generation, batch.slots.clone());
        drop(batch);
        let actions = py
            .detach(|| lock(&pool).native_act(&self.inner, generation, &slots))
            .map_err(to_py)?;
        let n = actions.len();
        let flat: Vec<f64> = actions.into_iter().flatten().collect();
        flat.into_pyarray(py).reshape([n, osms_sim::N_ACTION])
    }

    fn __repr__(&self) -> String {
        format!("NativePolicy({:?})", self.inner.name())
    }
}

/// What a pool observed at one control step, for a native policy to read the rollouts' state.
#[pyclass(name = "Batch", module = "osms._native", frozen)]
struct PyBatch {
    pool: Arc<Mutex<Pool>>,
    generation: u64,
    slots: Vec<usize>,
}

/// Rollouts of a protocol stepped in lockstep for one batch policy (`osms.eval.evaluate`).
#[pyclass(name = "Pool", module = "osms._native")]
struct PyPool {
    pool: Arc<Mutex<Pool>>,
    privileged: bool,
    /// The slots of the last observation, awaiting actions.
    observed: Vec<usize>,
}

#[pymethods]
impl PyPool {
    /// Rollouts of `protocol` on conditions `indices`, `n_envs` at a time. With `policy` (a
    /// NativePolicy) they run under that policy's rollout spec, as its own evaluation does;
    /// `privileged` adds the privileged frame to the observations.
    #[new]
    #[pyo3(signature = (protocol, indices, n_envs, policy=None, privileged=false))]
    fn new(
        protocol: &PyProtocol,
        indices: Vec<i64>,
        n_envs: i64,
        policy: Option<PyRef<'_, PyNative>>,
        privileged: bool,
    ) -> PyResult<Self> {
        let n_envs = usize::try_from(n_envs)
            .ok()
            .filter(|&n| n >= 1)
            .ok_or_else(|| {
                PyValueError::new_err(format!(
                    "n_envs is {n_envs}; it must be at least 1 (rollouts stepped at once)"
                ))
            })?;
        let protocol = protocol.inner.clone();
        let (spec, reads) = match &policy {
            Some(p) => (
                p.inner.spec(&protocol),
                p.inner.reads_contact_force() || privileged,
            ),
            None => (external_spec(&protocol), privileged),
        };
        let pool = Pool::new(protocol, spec, reads, indices, n_envs).map_err(to_py)?;
        Ok(PyPool {
            pool: Arc::new(Mutex::new(pool)),
            privileged,
            observed: Vec::new(),
        })
    }

    /// Starts rollouts in free slots and observes every running one (GIL released): a dict of
    /// `agent_pos` (n × 76, float32), `environment_state` (n × 85, if privileged), `condition`
    /// and `step` (n, int64) and `osms_batch` (for the store's policies); None once all ended.
    fn observe<'py>(&mut self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyDict>>> {
        if !self.observed.is_empty() {
            return Err(OsmsError::new_err(
                "the last observation awaits its actions: call act() first",
            ));
        }
        let pool = self.pool.clone();
        let privileged = self.privileged;
        let (slots, generation, frames) = py.detach(|| {
            let mut pool = lock(&pool);
            let slots = pool.observe();
            let frames = frames_of(&pool, &slots, privileged);
            (slots, pool.generation(), frames)
        });
        if slots.is_empty() {
            return Ok(None);
        }
        let n = slots.len();
        let dict = observation_dict(py, n, frames)?;
        dict.set_item(
            "osms_batch",
            PyBatch {
                pool: self.pool.clone(),
                generation,
                slots: slots.clone(),
            },
        )?;
        self.observed = slots;
        Ok(Some(dict))
    }

    /// Runs one action per observed rollout (`actions`: n × 24, float64, in observation order),
    /// GIL released. An action the world cannot run raises ActionError and moves nothing: the
    /// observation still awaits its actions.
    fn act(&mut self, py: Python<'_>, actions: &Bound<'_, PyAny>) -> PyResult<()> {
        let n = self.observed.len();
        if n == 0 {
            return Err(OsmsError::new_err(
                "no observation awaits actions: call observe() first",
            ));
        }
        let shape_error = |got: String| {
            let pool = lock(&self.pool);
            let (condition, step) = (
                pool.condition(self.observed[0]),
                pool.step(self.observed[0]),
            );
            to_py(GymError::Action {
                condition,
                step,
                problem: osms_gym::ActionProblem::Shape {
                    expected: format!(
                        "a float64 array of shape ({n}, {}): one row per observed rollout",
                        osms_sim::N_ACTION
                    ),
                    got,
                },
            })
        };
        let Ok(array) = actions.extract::<PyReadonlyArray2<'_, f64>>() else {
            let got = match actions.getattr("shape") {
                Ok(shape) => format!("{} of shape {}", type_name(actions), shape),
                Err(_) => type_name(actions),
            };
            return Err(shape_error(got));
        };
        let view = array.as_array();
        let shape = view.shape().to_vec();
        if shape != [n, osms_sim::N_ACTION] {
            return Err(shape_error(format!("{shape:?}")));
        }
        let rows: Vec<(usize, Vec<f64>)> = self
            .observed
            .iter()
            .zip(view.rows())
            .map(|(&k, row)| (k, row.to_vec()))
            .collect();
        let pool = self.pool.clone();
        py.detach(|| lock(&pool).act(rows)).map_err(to_py)?;
        self.observed.clear();
        Ok(())
    }

    /// Whether every rollout has ended.
    #[getter]
    fn done(&self) -> bool {
        lock(&self.pool).is_done()
    }

    /// The rows of the ended rollouts as `rollouts.csv` (the columns of `osms export eval_*`).
    fn rows_csv(&self) -> PyResult<String> {
        let pool = lock(&self.pool);
        osms_gym::rows_csv(&pool.rows().map_err(to_py)?).map_err(to_py)
    }
}

/// A Python value's type name, for an error message (`NoneType`, `list`, `numpy.ndarray`).
fn type_name(value: &Bound<'_, PyAny>) -> String {
    value
        .get_type()
        .name()
        .map(|n| n.to_string())
        .unwrap_or_else(|_| "an object".to_string())
}

/// The rollout spec of a policy outside osms: the protocol's, showing one frame (a policy keeps
/// its own history).
fn external_spec(protocol: &Protocol) -> osms_sim::RolloutSpec {
    let mut spec = protocol.rules.rollout.clone();
    spec.history_steps = 1;
    spec
}

/// The observed frames of `slots`, flattened, as float32: deployable, and privileged if asked.
struct Frames {
    deployable: Vec<f32>,
    privileged: Option<Vec<f32>>,
    condition: Vec<i64>,
    step: Vec<i64>,
}

fn frames_of(pool: &Pool, slots: &[usize], privileged: bool) -> Frames {
    let mut f = Frames {
        deployable: Vec::new(),
        privileged: privileged.then(Vec::new),
        condition: Vec::new(),
        step: Vec::new(),
    };
    for &k in slots {
        let view = pool.view(k);
        f.deployable
            .extend(view.deployable.iter().map(|&v| v as f32));
        if let Some(p) = f.privileged.as_mut() {
            p.extend(view.privileged.iter().map(|&v| v as f32));
        }
        f.condition.push(pool.condition(k) as i64);
        f.step.push(pool.step(k) as i64);
    }
    f
}

fn observation_dict(py: Python<'_>, n: usize, f: Frames) -> PyResult<Bound<'_, PyDict>> {
    let dict = PyDict::new(py);
    dict.set_item(
        "agent_pos",
        f.deployable
            .into_pyarray(py)
            .reshape([n, osms_sim::policy::DEPLOYABLE_LEN])?,
    )?;
    if let Some(p) = f.privileged {
        dict.set_item(
            "environment_state",
            p.into_pyarray(py)
                .reshape([n, osms_sim::policy::PRIVILEGED_LEN])?,
        )?;
    }
    dict.set_item("condition", f.condition.into_pyarray(py))?;
    dict.set_item("step", f.step.into_pyarray(py))?;
    Ok(dict)
}

/// Side of a rendered frame (pixels).
const RENDER_SIDE: u32 = 480;

/// One rollout at a time (the gymnasium environment's core). Bound to the thread that made it:
/// an OpenGL context (the renderer's) is per thread.
#[pyclass(name = "Env", module = "osms._native", unsendable)]
struct PyEnv {
    inner: SingleEpisode,
    privileged: bool,
    renderers: Renderers,
}

#[pymethods]
impl PyEnv {
    #[new]
    #[pyo3(signature = (protocol, privileged=false))]
    fn new(protocol: &PyProtocol, privileged: bool) -> Self {
        let protocol = protocol.inner.clone();
        let spec = external_spec(&protocol);
        PyEnv {
            inner: SingleEpisode::new(protocol, spec, privileged),
            privileged,
            renderers: Vec::new(),
        }
    }

    /// Starts the protocol's rollout of condition `index`; its first observation.
    fn reset<'py>(&mut self, py: Python<'py>, index: i64) -> PyResult<Bound<'py, PyDict>> {
        py.detach(|| self.inner.reset(index)).map_err(to_py)?;
        self.observation(py)
    }

    /// Runs `action` (24 values in [-1, 1]); (observation, info). The observation is the last
    /// one once the rollout has ended.
    fn step<'py>(
        &mut self,
        py: Python<'py>,
        action: PyReadonlyArray1<'_, f64>,
    ) -> PyResult<(Bound<'py, PyDict>, Bound<'py, PyDict>)> {
        let action = action.as_array().to_vec();
        let info = py.detach(|| self.inner.step(&action)).map_err(to_py)?;
        let obs = if info.done {
            PyDict::new(py)
        } else {
            self.observation(py)?
        };
        Ok((obs, info_dict(py, &info)?))
    }

    /// The rollout's state: running, or ended with its outcome.
    fn info<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        info_dict(py, &self.inner.info())
    }

    /// The ended rollout's row as `rollouts.csv` (header and one line).
    fn row_csv(&self) -> PyResult<Option<String>> {
        self.inner
            .row()
            .map(|row| osms_gym::rows_csv(&[row]))
            .transpose()
            .map_err(to_py)
    }

    /// The current state drawn by MuJoCo's offscreen renderer (Mesa's OSMesa): an
    /// (height, width, 3) uint8 array. The renderer of each object variant is made once.
    fn render<'py>(
        &mut self,
        py: Python<'py>,
    ) -> PyResult<Option<Bound<'py, numpy::PyArray3<u8>>>> {
        let Some(episode) = self.inner.episode() else {
            return Ok(None);
        };
        draw(py, &mut self.renderers, self.inner.protocol(), episode).map(Some)
    }
}

/// The renderers of one thread, one per object variant, made on first use.
type Renderers = Vec<(osms_sim::ObjectVariant, osms_render::Renderer)>;

/// `episode`'s current state drawn by MuJoCo's offscreen renderer (Mesa's OSMesa): an
/// (height, width, 3) uint8 array.
fn draw<'py>(
    py: Python<'py>,
    renderers: &mut Renderers,
    protocol: &Protocol,
    episode: &osms_sim::Episode<'_>,
) -> PyResult<Bound<'py, numpy::PyArray3<u8>>> {
    let variant = episode.record().condition.variant;
    let renderer = match renderers.iter().position(|(v, _)| *v == variant) {
        Some(i) => &mut renderers[i].1,
        None => {
            let model =
                osms_render::render_model(&protocol.world, variant, RENDER_SIDE, RENDER_SIDE)
                    .map_err(|e| OsmsError::new_err(e.to_string()))?;
            let camera = osms_render::CameraSpec::catch_view(protocol.world.home_palm_pos);
            let r = osms_render::Renderer::new(&model, RENDER_SIDE, RENDER_SIDE, &camera)
                .map_err(|e| OsmsError::new_err(format!("{e}\nhint: rendering needs Mesa's offscreen OpenGL library libOSMesa.so.8 (Debian: `apt-get install libosmesa6`; in a checkout, `scripts/setup-render`)")))?;
            renderers.push((variant, r));
            &mut renderers.last_mut().expect("just pushed").1
        }
    };
    let image = renderer
        .frame(episode.data())
        .map_err(|e| OsmsError::new_err(e.to_string()))?;
    let (h, w) = (image.height as usize, image.width as usize);
    image.rgb.into_pyarray(py).reshape([h, w, 3])
}

impl PyEnv {
    fn observation<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let dict = PyDict::new(py);
        let Some(view) = self.inner.view() else {
            return Ok(dict);
        };
        let frame: Vec<f32> = view.deployable.iter().map(|&v| v as f32).collect();
        dict.set_item("agent_pos", PyArray1::from_vec(py, frame))?;
        if self.privileged {
            let p: Vec<f32> = view.privileged.iter().map(|&v| v as f32).collect();
            dict.set_item("environment_state", PyArray1::from_vec(py, p))?;
        }
        Ok(dict)
    }
}

/// Sub-environments stepped together in Rust with the GIL released: the core of
/// `osms.gym.CatchVectorEnv`. Bound to the thread that made it (its renderers).
#[pyclass(name = "VectorEnv", module = "osms._native", unsendable)]
struct PyVectorEnv {
    inner: VectorEpisodes,
    renderers: Renderers,
}

#[pymethods]
impl PyVectorEnv {
    /// `num_envs` sub-environments on `protocol`'s conditions; `autoreset` is gymnasium's
    /// `AutoresetMode` value (`NextStep`, `SameStep`, `Disabled`). With `policy` (a
    /// NativePolicy) the episodes run under that policy's rollout spec, so that it can act on
    /// them (`native_actions`); `max_episode_steps` truncates episodes the world has not ended.
    #[new]
    #[pyo3(signature = (protocol, num_envs, autoreset, policy=None, privileged=false, max_episode_steps=None))]
    fn new(
        protocol: &PyProtocol,
        num_envs: i64,
        autoreset: &str,
        policy: Option<PyRef<'_, PyNative>>,
        privileged: bool,
        max_episode_steps: Option<i64>,
    ) -> PyResult<Self> {
        let count = |what: &str, n: i64| {
            usize::try_from(n)
                .map_err(|_| PyValueError::new_err(format!("{what} is {n}; it must be at least 1")))
        };
        let num_envs = count("num_envs", num_envs)?;
        let max_episode_steps = max_episode_steps
            .map(|m| count("max_episode_steps", m))
            .transpose()?;
        let mode = match autoreset {
            "NextStep" => Autoreset::NextStep,
            "SameStep" => Autoreset::SameStep,
            "Disabled" => Autoreset::Disabled,
            other => {
                return Err(PyValueError::new_err(format!(
                    "autoreset mode {other:?} is not one of gymnasium's: NextStep, SameStep, Disabled (gymnasium.vector.AutoresetMode)"
                )));
            }
        };
        let protocol = protocol.inner.clone();
        let (spec, reads) = match &policy {
            Some(p) => {
                p.inner.check_protocol(&protocol).map_err(to_py)?;
                (p.inner.spec(&protocol), p.inner.reads_contact_force())
            }
            None => (external_spec(&protocol), false),
        };
        let inner = VectorEpisodes::new(
            protocol,
            spec,
            reads,
            privileged,
            num_envs,
            mode,
            max_episode_steps,
        )
        .map_err(to_py)?;
        Ok(PyVectorEnv {
            inner,
            renderers: Vec::new(),
        })
    }

    #[getter]
    fn num_envs(&self) -> usize {
        self.inner.num_envs()
    }

    /// Starts episodes in the sub-environments `starts` names, `(sub-environment, condition or
    /// None for the next one)` in order, GIL released; (observation of every sub-environment,
    /// infos of the reset ones with their `_key` masks).
    fn reset<'py>(
        &mut self,
        py: Python<'py>,
        starts: Vec<(usize, Option<i64>)>,
    ) -> PyResult<(Bound<'py, PyDict>, Bound<'py, PyDict>)> {
        let inner = &mut self.inner;
        let reports = py.detach(|| inner.reset(&starts)).map_err(to_py)?;
        let n = self.inner.num_envs();
        let mut infos: Vec<Option<&StepInfo>> = vec![None; n];
        for (k, r) in &reports {
            infos[*k] = Some(&r.info);
        }
        let obs = self.observations(py)?;
        Ok((obs, vector_infos(py, &infos)?))
    }

    /// Runs one action per sub-environment (`actions`: num_envs × 24, float64), GIL released;
    /// (observations, rewards, terminations, truncations, infos) as gymnasium's vector
    /// environments return them. Under SAME_STEP, infos hold `final_obs` and `final_info` of the
    /// episodes that ended. A refused action moves nothing.
    #[allow(clippy::type_complexity)]
    fn step<'py>(
        &mut self,
        py: Python<'py>,
        actions: PyReadonlyArray2<'_, f64>,
    ) -> PyResult<(
        Bound<'py, PyDict>,
        Bound<'py, PyArray1<f64>>,
        Bound<'py, PyArray1<bool>>,
        Bound<'py, PyArray1<bool>>,
        Bound<'py, PyDict>,
    )> {
        let rows: Vec<Vec<f64>> = actions
            .as_array()
            .rows()
            .into_iter()
            .map(|r| r.to_vec())
            .collect();
        let inner = &mut self.inner;
        let reports = py.detach(|| inner.step(&rows)).map_err(to_py)?;
        let infos: Vec<Option<&StepInfo>> = reports.iter().map(|r| Some(&r.info)).collect();
        let info = vector_infos(py, &infos)?;
        if reports.iter().any(|r| r.ended.is_some()) {
            let ended: Vec<Option<&StepInfo>> = reports
                .iter()
                .map(|r| r.ended.as_ref().map(|(_, i)| i))
                .collect();
            let final_obs: Vec<Py<PyAny>> = reports
                .iter()
                .map(|r| match &r.ended {
                    Some((frame, _)) => Ok(frame_dict(py, frame)?.into_any().unbind()),
                    None => Ok(py.None()),
                })
                .collect::<PyResult<_>>()?;
            let mask: Vec<bool> = reports.iter().map(|r| r.ended.is_some()).collect();
            info.set_item("final_obs", PyArray1::from_vec(py, final_obs))?;
            info.set_item("_final_obs", PyArray1::from_vec(py, mask.clone()))?;
            info.set_item("final_info", vector_infos(py, &ended)?)?;
            info.set_item("_final_info", PyArray1::from_vec(py, mask))?;
        }
        let rewards = PyArray1::from_vec(py, reports.iter().map(|r| r.reward).collect());
        let terminated = PyArray1::from_vec(py, reports.iter().map(|r| r.terminated).collect());
        let truncated = PyArray1::from_vec(py, reports.iter().map(|r| r.truncated).collect());
        Ok((self.observations(py)?, rewards, terminated, truncated, info))
    }

    /// The actions of the store's policy `policy` (the one the environment was made for) for
    /// the current observation, num_envs × 24 float64 (zeros for ended episodes), GIL released.
    fn native_actions<'py>(
        &mut self,
        py: Python<'py>,
        policy: PyRef<'_, PyNative>,
    ) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let inner = &mut self.inner;
        let native = &policy.inner;
        let actions = py.detach(|| inner.native_act(native)).map_err(to_py)?;
        let n = actions.len();
        let flat: Vec<f64> = actions.into_iter().flatten().collect();
        flat.into_pyarray(py).reshape([n, osms_sim::N_ACTION])
    }

    /// The condition sub-environment `k` runs (or ran); None before its first reset.
    fn condition(&self, k: usize) -> Option<usize> {
        self.inner.condition(k)
    }

    /// The rows of the episodes that ended by the world's rules, in the order they started, as
    /// `rollouts.csv` (None before any ended).
    fn rows_csv(&self) -> PyResult<Option<String>> {
        let rows = self.inner.rows();
        if rows.is_empty() {
            return Ok(None);
        }
        osms_gym::rows_csv(&rows).map(Some).map_err(to_py)
    }

    /// Sub-environment `k`'s current state drawn offscreen; None before its first reset.
    fn render<'py>(
        &mut self,
        py: Python<'py>,
        k: usize,
    ) -> PyResult<Option<Bound<'py, numpy::PyArray3<u8>>>> {
        let Some(episode) = self.inner.episode(k) else {
            return Ok(None);
        };
        draw(py, &mut self.renderers, self.inner.protocol(), episode).map(Some)
    }
}

impl PyVectorEnv {
    /// Every sub-environment's last observation, stacked (zeros before its first reset).
    fn observations<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let frames = self.inner.frames();
        let n = frames.len();
        let (dep, priv_) = (
            osms_sim::policy::DEPLOYABLE_LEN,
            osms_sim::policy::PRIVILEGED_LEN,
        );
        let mut deployable = Vec::with_capacity(n * dep);
        let mut privileged: Option<Vec<f32>> = None;
        for f in &frames {
            match f {
                Some(f) => {
                    deployable.extend_from_slice(&f.deployable);
                    if let Some(p) = &f.privileged {
                        privileged.get_or_insert_with(Vec::new).extend_from_slice(p);
                    }
                }
                None => deployable.extend(std::iter::repeat_n(0.0, dep)),
            }
        }
        let dict = PyDict::new(py);
        dict.set_item("agent_pos", deployable.into_pyarray(py).reshape([n, dep])?)?;
        if self.inner.privileged() {
            let mut p = privileged.unwrap_or_default();
            p.resize(n * priv_, 0.0);
            dict.set_item("environment_state", p.into_pyarray(py).reshape([n, priv_])?)?;
        }
        Ok(dict)
    }
}

/// One observation as the single environment returns it.
fn frame_dict<'py>(py: Python<'py>, frame: &osms_gym::Frame) -> PyResult<Bound<'py, PyDict>> {
    let dict = PyDict::new(py);
    dict.set_item("agent_pos", PyArray1::from_slice(py, &frame.deployable))?;
    if let Some(p) = &frame.privileged {
        dict.set_item("environment_state", PyArray1::from_slice(py, p))?;
    }
    Ok(dict)
}

/// The infos of sub-environments as gymnasium's vector environments give them: one array per
/// key over the sub-environments, beside a `_key` mask of those that have it (a sub-environment
/// without an entry has none; `v_rel_mps` and `f_max_n` only after a contact).
fn vector_infos<'py>(py: Python<'py>, infos: &[Option<&StepInfo>]) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    let has: Vec<bool> = infos.iter().map(Option::is_some).collect();
    let column =
        |f: &dyn Fn(&StepInfo) -> i64| infos.iter().map(|i| i.map_or(0, f)).collect::<Vec<i64>>();
    let flag = |f: &dyn Fn(&StepInfo) -> bool| {
        infos
            .iter()
            .map(|i| i.is_some_and(f))
            .collect::<Vec<bool>>()
    };
    let real = |f: &dyn Fn(&StepInfo) -> Option<f64>| {
        let values: Vec<f64> = infos
            .iter()
            .map(|i| i.and_then(f).unwrap_or(f64::NAN))
            .collect();
        let mask: Vec<bool> = infos.iter().map(|i| i.and_then(f).is_some()).collect();
        (values, mask)
    };
    let put = |key: &str, value: Bound<'py, PyAny>, mask: Vec<bool>| -> PyResult<()> {
        d.set_item(key, value)?;
        d.set_item(format!("_{key}"), PyArray1::from_vec(py, mask))
    };
    put(
        "condition",
        PyArray1::from_vec(py, column(&|i| i.condition as i64)).into_any(),
        has.clone(),
    )?;
    put(
        "steps",
        PyArray1::from_vec(py, column(&|i| i.steps as i64)).into_any(),
        has.clone(),
    )?;
    put(
        "is_success",
        PyArray1::from_vec(py, flag(&|i| i.success)).into_any(),
        has.clone(),
    )?;
    put(
        "completion",
        PyArray1::from_vec(py, flag(&|i| i.completion)).into_any(),
        has.clone(),
    )?;
    let (v, m) = real(&|i| i.v_rel_mps);
    put("v_rel_mps", PyArray1::from_vec(py, v).into_any(), m)?;
    let (v, m) = real(&|i| i.f_max_n);
    put("f_max_n", PyArray1::from_vec(py, v).into_any(), m)?;
    let (v, _) = real(&|i| Some(i.l_max_m));
    put("l_max_m", PyArray1::from_vec(py, v).into_any(), has.clone())?;
    let failures: Vec<Py<PyAny>> = infos
        .iter()
        .map(|i| match i {
            Some(i) => Ok(pyo3::types::PyTuple::new(py, &i.failures)?
                .into_any()
                .unbind()),
            None => Ok(py.None()),
        })
        .collect::<PyResult<_>>()?;
    put("failures", PyArray1::from_vec(py, failures).into_any(), has)?;
    Ok(d)
}

fn info_dict<'py>(py: Python<'py>, info: &StepInfo) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("condition", info.condition)?;
    d.set_item("steps", info.steps)?;
    d.set_item("done", info.done)?;
    d.set_item("is_success", info.success)?;
    d.set_item("completion", info.completion)?;
    d.set_item("v_rel_mps", info.v_rel_mps)?;
    d.set_item("f_max_n", info.f_max_n)?;
    d.set_item("l_max_m", info.l_max_m)?;
    d.set_item("failures", info.failures.clone())?;
    Ok(d)
}

/// Channel names: `agent_pos` (the deployable frame), `environment_state` (the privileged
/// frame) and `action`, as osms's LeRobot export names them.
#[pyfunction]
fn channels<'py>(py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("agent_pos", osms_export::state_names())?;
    d.set_item("environment_state", osms_export::environment_state_names())?;
    d.set_item("action", osms_export::action_names())?;
    Ok(d)
}

/// The Rust-native baseline of a Python-driven evaluation's speed (`scripts/bench-python`):
/// the rollouts of `indices` under the constant `action`, stepped in a pool of `n_envs` without
/// Python (`per_thread`: one rollout per task, as the evaluation stages run them). Returns
/// (control steps, wall seconds); the GIL is released throughout.
#[pyfunction]
#[pyo3(signature = (protocol, indices, n_envs, action, per_thread=false))]
fn bench_constant(
    py: Python<'_>,
    protocol: &PyProtocol,
    indices: Vec<i64>,
    n_envs: usize,
    action: Vec<f64>,
    per_thread: bool,
) -> PyResult<(usize, f64)> {
    let action = osms_gym::check_action(&action, 0, 0).map_err(to_py)?;
    let protocol = protocol.inner.clone();
    let spec = external_spec(&protocol);
    py.detach(|| {
        let started = std::time::Instant::now();
        let steps = if per_thread {
            osms_gym::baseline::per_thread(&protocol, &spec, &indices, action)
        } else {
            osms_gym::baseline::pooled(protocol.clone(), spec.clone(), indices, n_envs, action)
        }?;
        Ok((steps, started.elapsed().as_secs_f64()))
    })
    .map_err(to_py)
}

/// The columns of `rollouts.csv`, in order.
#[pyfunction]
fn row_columns() -> Vec<String> {
    osms_export::rollouts::column_names()
}

/// The columns of `rollouts.csv` with their cell types (`int`, `float`, `bool`, `text`), in
/// order: how `osms.eval.Evaluation` parses them.
#[pyfunction]
fn row_column_types() -> Vec<(String, &'static str)> {
    osms_export::rollouts::column_types()
}

/// The Wilson score interval of `successes` out of `n` (95 % by default) as (low, high),
/// exactly 0 (1) at the lower (upper) end for 0 (`n`) successes; (nan, nan) for `n` = 0.
/// The same interval osms's own tables print.
#[pyfunction]
#[pyo3(signature = (successes, n, z=None))]
fn wilson(successes: i64, n: i64, z: Option<f64>) -> PyResult<(f64, f64)> {
    let (Ok(x), Ok(total)) = (usize::try_from(successes), usize::try_from(n)) else {
        return Err(PyValueError::new_err(format!(
            "wilson({successes}, {n}): counts are not negative"
        )));
    };
    if x > total {
        return Err(PyValueError::new_err(format!(
            "wilson({successes}, {n}): more successes than trials"
        )));
    }
    Ok(osms_gym::wilson(x, total, z).unwrap_or((f64::NAN, f64::NAN)))
}

/// The keys of osms's robomimic export's observations with their widths, in the deployable
/// frame's order (`agent_pos` split into them).
#[pyfunction]
fn robomimic_keys() -> Vec<(&'static str, usize)> {
    osms_export::robomimic::OBS_KEYS.to_vec()
}

#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    osms_sim::ffi::route_mujoco_logs_at_startup();
    m.add_class::<PyProject>()?;
    m.add_class::<PyProtocol>()?;
    m.add_class::<PyNative>()?;
    m.add_class::<PyBatch>()?;
    m.add_class::<PyPool>()?;
    m.add_class::<PyEnv>()?;
    m.add_class::<PyVectorEnv>()?;
    m.add_function(wrap_pyfunction!(channels, m)?)?;
    m.add_function(wrap_pyfunction!(row_columns, m)?)?;
    m.add_function(wrap_pyfunction!(row_column_types, m)?)?;
    m.add_function(wrap_pyfunction!(wilson, m)?)?;
    m.add_function(wrap_pyfunction!(robomimic_keys, m)?)?;
    m.add_function(wrap_pyfunction!(bench_constant, m)?)?;
    m.add("OsmsError", m.py().get_type::<OsmsError>())?;
    m.add("ActionError", m.py().get_type::<ActionError>())?;
    m.add("N_ACTION", osms_sim::N_ACTION)?;
    m.add("DEPLOYABLE_LEN", osms_sim::policy::DEPLOYABLE_LEN)?;
    m.add("PRIVILEGED_LEN", osms_sim::policy::PRIVILEGED_LEN)?;
    // The default world's control rate; a protocol's own is `Protocol.control_hz`.
    m.add(
        "DEFAULT_CONTROL_HZ",
        1.0 / osms_sim::WorldSpec::default().control_dt_secs(),
    )?;
    // The default protocol's episode limit: `osms/Catch-v0` is registered with it.
    m.add(
        "DEFAULT_MAX_STEPS",
        max_steps(
            osms_sim::SuccessSpec::default().max_episode_secs,
            osms_sim::WorldSpec::default().control_dt_secs(),
        ),
    )?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
