//! The crate's only unsafe code: Mesa's off-screen OpenGL (OSMesa), loaded at run time, and
//! MuJoCo's rendering context on top of it. The workspace denies `unsafe_code`; this module
//! allows it (like osms-sim's `ffi`), with a `SAFETY` comment on every block.
//!
//! `libOSMesa.so.8` is opened with `RTLD_NOW | RTLD_GLOBAL` and never closed: MuJoCo's GL loader
//! (glad) finds `OSMesaGetProcAddress` through `dlopen(NULL)` and keeps the pointer for the rest
//! of the process. Nothing links against Mesa, so the workspace builds without it.
//!
//! A GL context is bound to a thread: [`GlContext`] holds a raw pointer and [`MjrContext`] is
//! `!Send`, so it can neither move to nor be shared with another thread.
#![allow(unsafe_code)]

use std::ffi::{CStr, c_char, c_int, c_uint, c_void};
use std::mem::ManuallyDrop;
use std::sync::OnceLock;

use mujoco_rs::prelude::*;
use mujoco_rs::wrappers::mj_rendering::MjrContext;

use crate::RenderError;

/// The library's file name (Debian package `libosmesa6`).
pub const OSMESA_LIB: &str = "libOSMesa.so.8";

const OSMESA_RGBA: c_uint = 0x1908; // GL_RGBA
const GL_UNSIGNED_BYTE: c_uint = 0x1401;

type CreateContextExt =
    unsafe extern "C" fn(c_uint, c_int, c_int, c_int, *mut c_void) -> *mut c_void;
type MakeCurrent = unsafe extern "C" fn(*mut c_void, *mut c_void, c_uint, c_int, c_int) -> u8;
type DestroyContext = unsafe extern "C" fn(*mut c_void);

/// The three OSMesa entry points osms uses. Plain function pointers: `Send` and `Sync`.
struct OsMesa {
    create_context_ext: CreateContextExt,
    make_current: MakeCurrent,
    destroy_context: DestroyContext,
}

static OSMESA: OnceLock<Result<OsMesa, String>> = OnceLock::new();

fn dlerror() -> String {
    // SAFETY: dlerror returns null or a pointer to a NUL-terminated, thread-local message that
    // stays valid until the next dl* call on this thread; it is copied out at once.
    unsafe {
        let msg = libc::dlerror();
        if msg.is_null() {
            "unknown dlopen error".to_string()
        } else {
            CStr::from_ptr(msg).to_string_lossy().into_owned()
        }
    }
}

fn load() -> Result<OsMesa, String> {
    let name = c"libOSMesa.so.8";
    // SAFETY: `name` is a NUL-terminated string; loading Mesa runs only its own initialisers.
    // The handle is deliberately never closed (MuJoCo keeps pointers into the library).
    let handle = unsafe { libc::dlopen(name.as_ptr(), libc::RTLD_NOW | libc::RTLD_GLOBAL) };
    if handle.is_null() {
        return Err(dlerror());
    }
    let symbol = |sym: &CStr| -> Result<*mut c_void, String> {
        // SAFETY: `handle` is a live handle from dlopen and `sym` is NUL-terminated.
        let p = unsafe { libc::dlsym(handle, sym.as_ptr() as *const c_char) };
        if p.is_null() {
            Err(format!(
                "{OSMESA_LIB} has no symbol {}",
                sym.to_string_lossy()
            ))
        } else {
            Ok(p)
        }
    };
    let create = symbol(c"OSMesaCreateContextExt")?;
    let make_current = symbol(c"OSMesaMakeCurrent")?;
    let destroy = symbol(c"OSMesaDestroyContext")?;
    // SAFETY: the symbols are OSMesa's exported functions with the C signatures declared by
    // GL/osmesa.h (OSMesaContext is an opaque pointer, GLenum/GLint/GLsizei are 32-bit
    // integers, GLboolean is a byte), which the function pointer types above repeat.
    unsafe {
        Ok(OsMesa {
            create_context_ext: std::mem::transmute::<*mut c_void, CreateContextExt>(create),
            make_current: std::mem::transmute::<*mut c_void, MakeCurrent>(make_current),
            destroy_context: std::mem::transmute::<*mut c_void, DestroyContext>(destroy),
        })
    }
}

fn osmesa() -> Result<&'static OsMesa, RenderError> {
    OSMESA
        .get_or_init(load)
        .as_ref()
        .map_err(|detail| RenderError::NoOsMesa {
            detail: detail.clone(),
        })
}

/// Whether `libOSMesa.so.8` can be loaded (it stays loaded once it has been).
pub fn osmesa_available() -> Result<(), RenderError> {
    osmesa().map(|_| ())
}

/// An OSMesa context with MuJoCo's rendering context (offscreen framebuffer, uploaded meshes
/// and textures) created in it. Dropping it frees MuJoCo's context with the GL context current,
/// then destroys the GL context.
pub struct GlContext {
    ctx: *mut c_void,
    fns: &'static OsMesa,
    /// OSMesa's default (window) framebuffer. MuJoCo draws into its own offscreen framebuffer
    /// object; this buffer only has to outlive the context, at a stable address.
    buffer: Vec<u8>,
    width: c_int,
    height: c_int,
    mjr: ManuallyDrop<MjrContext>,
}

impl GlContext {
    /// Creates a `width` × `height` OSMesa context (RGBA, 24-bit depth, 8-bit stencil), makes it
    /// current on this thread and creates MuJoCo's rendering context for `model` in it. The
    /// model's offscreen buffer size (`vis.global.offwidth/offheight`) must already be the
    /// wanted size.
    pub fn new(model: &MjModel, width: u32, height: u32) -> Result<Self, RenderError> {
        let fns = osmesa()?;
        let size_error = || RenderError::Size { width, height };
        let w = c_int::try_from(width).map_err(|_| size_error())?;
        let h = c_int::try_from(height).map_err(|_| size_error())?;
        let bytes = (width as usize)
            .checked_mul(height as usize)
            .and_then(|n| n.checked_mul(4))
            .ok_or_else(size_error)?;
        // SAFETY: OSMesaCreateContextExt takes plain integers and a null share list; it
        // returns null on failure, which is checked.
        let ctx = unsafe { (fns.create_context_ext)(OSMESA_RGBA, 24, 8, 0, std::ptr::null_mut()) };
        if ctx.is_null() {
            return Err(RenderError::Gl(
                "OSMesaCreateContextExt failed to create an RGBA context".into(),
            ));
        }
        let mut buffer = vec![0u8; bytes];
        // SAFETY: `ctx` is a live context and `buffer` holds width × height RGBA bytes of
        // GL_UNSIGNED_BYTE, as OSMesaMakeCurrent requires.
        let ok =
            unsafe { (fns.make_current)(ctx, buffer.as_mut_ptr().cast(), GL_UNSIGNED_BYTE, w, h) };
        if ok == 0 {
            // SAFETY: `ctx` is live and is not used again.
            unsafe { (fns.destroy_context)(ctx) };
            return Err(RenderError::Gl(format!(
                "OSMesaMakeCurrent failed for a {width}x{height} buffer"
            )));
        }
        // SAFETY: the OSMesa context was just made current on this thread and stays so for the
        // call. The MjrContext lives inside this GlContext, which is !Send (raw pointer), so it
        // stays on this thread, and Drop makes the context current again before freeing it.
        let mjr = unsafe { MjrContext::new(model) };
        Ok(GlContext {
            ctx,
            fns,
            buffer,
            width: w,
            height: h,
            mjr: ManuallyDrop::new(mjr),
        })
    }

    fn make_current(&mut self) {
        // SAFETY: `self.ctx` is live until Drop and `self.buffer` has the size it was created
        // with. Re-binding the same context and buffer cannot fail once it has succeeded.
        unsafe {
            (self.fns.make_current)(
                self.ctx,
                self.buffer.as_mut_ptr().cast(),
                GL_UNSIGNED_BYTE,
                self.width,
                self.height,
            );
        }
    }

    /// Makes this context current on the calling thread (another renderer on the thread may
    /// have bound its own) and returns MuJoCo's rendering context for drawing and reading.
    pub fn current(&mut self) -> &mut MjrContext {
        self.make_current();
        &mut self.mjr
    }
}

impl Drop for GlContext {
    fn drop(&mut self) {
        self.make_current();
        // SAFETY: the GL context that MjrContext was created in is current on this thread (the
        // type is !Send, so this is the creating thread); `mjr` is dropped exactly once, here,
        // and the GL context is destroyed only after it.
        unsafe {
            ManuallyDrop::drop(&mut self.mjr);
            (self.fns.destroy_context)(self.ctx);
        }
    }
}
