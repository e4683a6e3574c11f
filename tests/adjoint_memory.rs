//! Memory of the eikonal adjoint: the constant-memory pass (ray reconstructed by
//! reversing the integrator) must not allocate more for more steps; the stored-path (tape) pass
//! grows linearly. Measured with a counting global allocator (bytes requested by this thread during
//! the call, so tests running in parallel do not disturb each other).

use glam::DVec3;
use lightpath::eikonal::{BoundedField, Bounds, FieldParam, GridAdjoint, Profile, Ray, Tracer};
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

struct Counting;
thread_local! {
    static BYTES: Cell<usize> = const { Cell::new(0) };
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let _ = BYTES.try_with(|b| b.set(b.get() + layout.size()));
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

fn allocated(f: impl FnOnce()) -> usize {
    let before = BYTES.with(Cell::get);
    f();
    BYTES.with(Cell::get) - before
}

#[test]
fn adjoint_memory_does_not_grow_with_steps() {
    let field = BoundedField::single(
        Profile::ParabolicFibre {
            n0: 1.5,
            alpha: 0.3,
        },
        Bounds::Everywhere,
        1.0,
    );
    let t = Tracer {
        field: &field,
        step: 1e-3,
        max_steps: 0,
    };
    let r0 = Ray {
        x: DVec3::new(0.3, 0.1, 0.0),
        v: DVec3::new(0.1, 0.0, 1.0).normalize() * 1.4,
    };
    let params = [FieldParam {
        profile: 0,
        which: 1,
    }];
    let loss_grad = |r: Ray| (r.x, DVec3::ZERO);
    let mut reversed = Vec::new();
    let mut tape = Vec::new();
    for steps in [1_000, 10_000, 100_000] {
        reversed.push(allocated(|| {
            t.adjoint(r0, steps, 1e-3, &params, loss_grad).unwrap();
        }));
        tape.push(allocated(|| {
            t.adjoint_tape(r0, steps, 1e-3, &params, loss_grad).unwrap();
        }));
    }
    eprintln!("bytes allocated for 1e3, 1e4, 1e5 steps: reversed {reversed:?}, tape {tape:?}");
    assert!(reversed.iter().all(|&b| b == reversed[0]), "{reversed:?}");
    assert!(reversed[0] < 1024, "{reversed:?}");
    // the tape stores every state: 48 bytes a step
    assert!(tape[2] >= 48 * 100_000, "{tape:?}");
}

/// The same for the exit adjoint through a grid, with a gradient buffer the caller owns: no
/// allocation grows with the path length (only the list of reflection segments, one here).
#[test]
fn exit_adjoint_memory_does_not_grow_with_steps() {
    let field = BoundedField::single(
        Profile::Luneburg { radius: 1.0 },
        Bounds::Sphere { radius: 1.0 },
        1.0,
    );
    let mut bytes = Vec::new();
    for step in [1e-2, 1e-3, 1e-4] {
        let t = Tracer {
            field: &field,
            step,
            max_steps: 1_000_000,
        };
        bytes.push(allocated(|| {
            let g = t
                .exit_adjoint(
                    DVec3::new(0.2, 0.1, -2.0),
                    DVec3::Z,
                    &[FieldParam {
                        profile: 0,
                        which: 0,
                    }],
                    None::<GridAdjoint>,
                    |e| (e.x, DVec3::ZERO),
                )
                .unwrap();
            assert!(g.end.steps >= (1.0 / step) as usize);
        }));
    }
    eprintln!("exit adjoint bytes for steps 1e-2, 1e-3, 1e-4: {bytes:?}");
    assert!(bytes.iter().all(|&b| b == bytes[0]), "{bytes:?}");
}
