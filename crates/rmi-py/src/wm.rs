//! `GruForecaster`: the fused world-model rollout of the `rmi-wm` crate, for
//! `rmi_learn.world_models.gru` (numpy `float32` in and out, GIL released while it runs).

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

use numpy::{PyArray1, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray3, PyUntypedArrayMethods};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use rmi_wm::model::Inputs;
use rmi_wm::{GruWorldModel, Spec, Tensor, WmError};

use crate::panic::{catch, into_py};

/// A rollout's error as the engine's, so that it raises the same `ConfigError` with the same
/// text and fields.
fn core_error(e: WmError) -> rmi_sph::RmiError {
    match e {
        WmError::InvalidConfig { field, value, expected } => {
            rmi_sph::RmiError::InvalidConfig { field, value, expected }
        }
    }
}

/// Free rollout of a trained AC-GRU-WM or State-GRU-WM in one native call.
///
/// Parameters
/// ----------
/// state : dict[str, numpy.ndarray]
///     The model's ``state_dict`` as ``float32`` arrays (torch names: ``encoder.weight_ih_l0``,
///     ``decoder.0.weight_ih``, ``E_u.0.weight`` (AC-GRU-WM only), ``head.weight``, ...).
/// keep : numpy.ndarray
///     ``obs_keep``, one float per observation channel (1 kept, 0 ablated).
/// assemble : list[int]
///     ``ASSEMBLE_INDEX``: per observation channel, its position in the head output.
/// continuous : list[int]
///     ``CONTINUOUS_INDEX``: observation channel of each continuous state entry.
///
/// Raises
/// ------
/// ConfigError
///     A weight is missing, misshapen or not finite (``err.field`` names it).
#[pyclass(name = "GruForecaster", module = "rmi_sph")]
pub struct PyGruForecaster {
    model: GruWorldModel,
    /// The last pool used (rebuilt when the thread count changes); behind a lock so that
    /// several Python threads may score with one forecaster at once.
    pool: Mutex<Option<Arc<rayon::ThreadPool>>>,
}

#[pymethods]
impl PyGruForecaster {
    #[new]
    fn new(
        state: &Bound<'_, PyDict>,
        keep: PyReadonlyArray1<'_, f32>,
        assemble: Vec<usize>,
        continuous: Vec<usize>,
    ) -> PyResult<Self> {
        let mut weights = HashMap::new();
        for (k, v) in state.iter() {
            let name: String = k.extract()?;
            let arr = v
                .cast_into::<numpy::PyArrayDyn<f32>>()
                .map_err(|_| PyValueError::new_err(format!("state[{name:?}] must be a float32 numpy array")))?;
            let ro = arr.readonly();
            let data = ro.as_array().iter().copied().collect();
            weights.insert(name, Tensor { shape: ro.shape().to_vec(), data });
        }
        let spec = Spec { keep: keep.as_array().to_vec(), assemble, continuous };
        let model = into_py(catch(|| GruWorldModel::from_state(&weights, spec).map_err(core_error)))?;
        Ok(PyGruForecaster { model, pool: Mutex::new(None) })
    }

    /// Whether this CPU runs the rollout's AVX2 + FMA copy. Without it (or with
    /// ``RMI_NO_AVX2`` set) the fused multiply-adds are library calls and the rollout is
    /// much slower than torch's, so ``rmi_learn`` then keeps inference in torch.
    #[staticmethod]
    fn accelerated() -> bool {
        rmi_par::cpu::avx2_enabled()
    }

    /// Whether the model reads the commands (AC-GRU-WM).
    #[getter]
    fn action_conditioned(&self) -> bool {
        self.model.action_conditioned()
    }

    /// Rolls out ``n`` command chunks against ``b`` histories (chunk ``i`` uses history
    /// ``i // (n // b)``), all standardised as in the dataset.
    ///
    /// Parameters
    /// ----------
    /// hist, hist_mask : numpy.ndarray
    ///     ``(b, L, 23)`` float32 observations and their validity mask.
    /// actions : numpy.ndarray
    ///     ``(n, H, 2)`` float32 commands.
    /// num_threads : int, default 1
    ///     Threads sharing the chunks; results are the same bits for any count.
    ///
    /// Returns
    /// -------
    /// tuple of numpy.ndarray
    ///     ``z`` (n, H, 18), ``contact_logit`` (n, H), ``friction_logit`` (n, H, 4).
    #[pyo3(signature = (hist, hist_mask, actions, *, num_threads=1))]
    fn forecast<'py>(
        &self,
        py: Python<'py>,
        hist: PyReadonlyArray3<'py, f32>,
        hist_mask: PyReadonlyArray3<'py, f32>,
        actions: PyReadonlyArray3<'py, f32>,
        num_threads: i64,
    ) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyAny>, Bound<'py, PyAny>)> {
        let num_threads = usize::try_from(num_threads)
            .map_err(|_| rmi_sph::simulation::threads_error(num_threads))
            .and_then(rmi_sph::simulation::check_threads)
            .map_err(crate::errors::to_pyerr)?;
        let pool = if num_threads > 1 {
            let mut cached = self.pool.lock().unwrap_or_else(|e| e.into_inner());
            match cached.as_ref() {
                Some(p) if p.current_num_threads() == num_threads => Some(Arc::clone(p)),
                _ => {
                    let p = rayon::ThreadPoolBuilder::new().num_threads(num_threads).build();
                    let p = Arc::new(
                        p.map_err(|e| PyValueError::new_err(format!("cannot start {num_threads} threads: {e}")))?,
                    );
                    *cached = Some(Arc::clone(&p));
                    Some(p)
                }
            }
        } else {
            None
        };
        let (hs, ms, us) = (hist.shape().to_vec(), hist_mask.shape().to_vec(), actions.shape().to_vec());
        if ms != hs {
            return Err(PyValueError::new_err(format!("hist_mask has shape {ms:?}, hist {hs:?}")));
        }
        // Copied out (any strides) so that the rollout runs without the GIL.
        let owned = |a: &PyReadonlyArray3<'py, f32>| a.as_array().iter().copied().collect::<Vec<f32>>();
        let (h_vec, m_vec, u_vec) = (owned(&hist), owned(&hist_mask), owned(&actions));
        let x =
            Inputs { hist: &h_vec, mask: &m_vec, actions: &u_vec, b: hs[0], l: hs[1], n: us[0], h: us[1], n_u: us[2] };
        let model = &self.model;
        let f = into_py(py.detach(|| catch(|| model.forecast(x, pool.as_deref()).map_err(core_error))))?;
        let (n, h) = (us[0], us[1]);
        let z = PyArray1::from_vec(py, f.z).reshape([n, h, self.model.n_z()])?.into_any();
        let c = PyArray1::from_vec(py, f.contact_logit).reshape([n, h])?.into_any();
        let fr = PyArray1::from_vec(py, f.friction_logit).reshape([n, h, self.model.n_fric()])?.into_any();
        Ok((z, c, fr))
    }
}
