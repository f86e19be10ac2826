/*
 * The fast lane: the hot calls of a step (fmi2SetReal of the inputs, fmi2DoStep, fmi2Get* of the
 * outputs) answered by compiled code on arrays the slave shares, without entering the interpreter.
 *
 * A slave that can (fmu_src/fast_lane.py) hands the loader the address of a Lane it owns, through
 * the logger, in a message of category LANE_CATEGORY ("<address>", "0" to withdraw it).  The
 * Lane holds the slave's variables as three arrays indexed by value reference (Real, Integer,
 * Boolean), a flag byte per value reference, and a compiled step (a numba cfunc,
 * solver/_kernels/c_entry.py) with its table.  Both sides keep the arrays consistent at the border:
 *  - before any call the loader forwards to Python, if the lane changed values (py_stale), the
 *    loader calls the slave's ``pull`` (the slave reads the arrays into its attributes);
 *  - after any forwarded call, the loader calls the slave's ``push`` (the slave writes its
 *    attributes, its committed state and whether the lane may serve now, ``enabled``).
 * The lane serves only in stepComplete, with ``enabled`` set, and only calls whose every value
 * reference it may serve (``flags``); an output while an input was set since the last step
 * (``dirty``: direct feedthrough) goes to Python.  Its step returns LANE_PUBLISHED when it took the
 * step; otherwise (FALL_BACK: not routine, an episode to log, a value not finite; it has undone itself;
 * or 0: a compiled kernel raised) the loader forwards the doStep to Python, which takes the same step
 * from the committed state and logs or refuses as it always does.
 *
 * FMI 3.0 (layout version 2).  The FMI 3.0 DK FMU's variables are arrays over its core's scalars
 * (fmu_src/fmi3_adapter.py): its value reference k is the core's value references first3[k] ..
 * first3[k] + count3[k] - 1 (first3[k] < 0: not served), and the lane3_* calls take FMI 3.0's
 * arguments (value references, then the number of values) on the same arrays.
 */
#ifndef RRR_DK_FAST_LANE_H
#define RRR_DK_FAST_LANE_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

/* the logger category of the slave's lane hand-over */
#define LANE_CATEGORY "rrrdkFastLane"
/* the layout version of Lane (fmu_src/fast_lane.py: VERSION) */
#define LANE_VERSION 2

/* flags[vr] bits */
#define LANE_REAL 1u      /* a Real variable */
#define LANE_INTEGER 2u   /* an Integer variable */
#define LANE_BOOLEAN 4u   /* a Boolean variable */
#define LANE_SET 8u       /* settable in stepComplete (an input) */
#define LANE_OUTPUT 16u   /* an output of direct feedthrough: stale while dirty */
#define LANE_DIRTIES 32u  /* an input whose set makes the outputs of direct feedthrough stale */

/* the command of the compiled step that takes a published step (solver/_kernels/c_entry.py CMD_PUBLISH),
 * and what it returns when it published (PUBLISHED; anything else: the call goes to Python) */
#define LANE_CMD_PUBLISH 2
#define LANE_PUBLISHED 2

typedef struct {
    int64_t version;          /* LANE_VERSION */
    int64_t enabled;          /* the slave lets the lane serve now */
    int64_t py_stale;         /* the lane changed values the slave has not read */
    int64_t dirty;            /* an input was set since the outputs were computed */
    int64_t n_vr;             /* value references 0 .. n_vr - 1 */
    double* real;             /* Real values by value reference */
    int32_t* integer;         /* Integer values */
    int32_t* boolean;         /* Boolean values (fmi2Boolean: int) */
    uint8_t* flags;           /* LANE_* bits by value reference */
    int64_t (*step)(void* table, int64_t cmd, double t, double h);   /* LANE_PUBLISHED, else fall back */
    void* table;              /* the step's table */
    void* pull;               /* PyObject*: the slave's bound method that reads the arrays */
    void* push;               /* PyObject*: the slave's bound method that writes them */
    int64_t fast_steps;       /* doSteps the lane took (diagnostics; the slave reads it) */
    int64_t fast_calls;       /* get/set calls the lane answered (diagnostics) */
    int64_t n_vr3;            /* FMI 3.0 value references 0 .. n_vr3 - 1 (0: no FMI 3.0 map) */
    int64_t* first3;          /* the first core value reference of each (-1: not served) */
    int64_t* count3;          /* how many consecutive core value references each is made of */
} Lane;

/* The lane of the hand-over message ``text`` (NULL for "0" or a Lane of another version; ``why``
 * then says what was wrong, "" for a withdrawal) */
Lane* lane_take(const char* text, char* why, size_t why_size);
/* may the lane serve a call now: registered, enabled, in stepComplete (``state_ok``) */
static inline int lane_open(const Lane* lane, int state_ok) { return lane && state_ok && lane->enabled; }
/* the calls: 1 when the lane answered (the values are set or read), 0 when the call goes to Python */
int lane_set_real(Lane* lane, const unsigned vr[], size_t n, const double v[]);
int lane_get_real(Lane* lane, const unsigned vr[], size_t n, double v[]);
int lane_get_integer(Lane* lane, const unsigned vr[], size_t n, int v[]);
int lane_get_boolean(Lane* lane, const unsigned vr[], size_t n, int v[]);
int lane_do_step(Lane* lane, double t, double h);
/* the FMI 3.0 calls, by FMI 3.0 value reference (``nvr`` of them, ``n`` values in all) */
int lane3_set_float64(Lane* lane, const uint32_t vr[], size_t nvr, const double v[], size_t n);
int lane3_get_float64(Lane* lane, const uint32_t vr[], size_t nvr, double v[], size_t n);
int lane3_get_int32(Lane* lane, const uint32_t vr[], size_t nvr, int32_t v[], size_t n);
int lane3_get_boolean(Lane* lane, const uint32_t vr[], size_t nvr, bool v[], size_t n);
/* before and after a call forwarded to Python: the slave's pull (when the lane changed values) and
 * push; -1 (and the lane should be dropped) when Python raised */
int lane_before_python(Lane* lane);
int lane_after_python(Lane* lane);

#endif
