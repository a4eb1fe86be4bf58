/*
  lfstudio test harness: a small link-time shim for the official GRBL 1.1h simulator (grbl-sim).

  The firmware sources (grbl/*.c) and the simulator sources (grbl/grbl-sim/*.c) are compiled
  unchanged by their own Makefile; this file is added to the link and four simulator functions are
  wrapped with the linker's --wrap option. Nothing of the firmware's behaviour is replaced.

  1. platform_poll_stdin: grbl-sim toggles the terminal mode and calls select() for every simulated
     bit time (~470 000 times per simulated second, four system calls each), which makes the
     simulation run at a fraction of real time. Here stdin is polled once every 64 calls and read
     in chunks; one byte per call is handed to the simulated UART as before. End of input (the
     host closed the pseudo-terminal) ends the process.
  2. grbl_per_tick (the simulator's per-clock-tick hook):
     - input pins idle high like a real board with pull-ups (grbl-sim leaves them at 0, so every
       limit, control and probe pin reads "triggered": Pn:PXYZRHS in every status report);
     - optional limit switches: LFSTUDIO_GRBL_SIM_SWITCHES="xmin:xmax,ymin:ymax,zmin:zmax" in mm
       from the power-up position (an empty side has no switch). The carriage's physical position
       follows the step counts (sys_position changes by at most one step per tick; a larger jump
       is the firmware re-defining its machine coordinates, e.g. after homing, not motion; an axis
     locked by the homing cycle is counted but not stepped by the firmware). A pin
       change calls the firmware's own limit pin-change interrupt (hard limits, $21);
     - lockstep with the firmware's main loop: the stepper interrupt runs in the simulator thread,
       the step segments are prepared by the firmware's main loop in another thread. On a loaded
       machine the simulator thread could outrun the main loop and drain the segment buffer, which
       makes the firmware stop mid-move (an artifact no real board shows). While the stepper timer
       runs, every LFSTUDIO_LOCKSTEP_US of simulated time waits until the main loop has prepared
       segments again (st_prep_buffer), so results do not depend on thread scheduling.
  3. st_prep_buffer: counts the main loop's segment preparations for the lockstep above.
  4. platform_sleep: grbl-sim yields with nanosleep(0) in busy loops (both threads spin at full
     speed even when idle); a minimum of 100 us keeps an idle simulator at a few percent of a core.
  5. eeprom_put_char: flushed at once, so settings survive a power cycle (SIGKILL) of the process.
  6. Interrupt atomicity. On the AVR an interrupt handler never runs in the middle of main-program
     code and vice versa; grbl-sim runs the handlers in a second thread, truly in parallel. The
     read-modify-writes of GRBL's realtime flags (system_set/clear_exec_*: the main loop clearing
     one flag could drop a '?' or '!' the serial handler had just set) and of the transmit ring
     (serial_write against the UDRE handler: stuck or repeated output bytes) are made atomic with
     one lock, as interrupts make them on the real chip. serial_write waits for room in the ring
     outside the lock (on the AVR the handler drains it while main waits).
  7. Spindle output log (read-only): with LFSTUDIO_GRBL_SIM_SPINDLE_LOG=path, every change of the
     spindle PWM output (on: the PWM enabled, SPINDLE_COMB_BIT in TCCR2A, with OCR2A > 0; what a
     camera's trigger input wired to it sees) is written as one line: simulated time in s, level,
     the step counts of X Y Z, OCR2A. The firmware sets it in its stepper interrupt as each step
     segment loads (laser mode, $32=1), so this shows where along the motion the output changes.
*/

#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <stdio.h>
#include <poll.h>
#include <pthread.h>
#include <time.h>
#include <unistd.h>

#include "simulator.h"
#include "avr/io.h"
#include "avr/interrupt.h"
#include "../grbl.h"

#define LFSTUDIO_LOCKSTEP_US 4000

uint8_t __real_platform_poll_stdin(void);
void __real_serial_write(uint8_t data);
void __real_interrupt_SERIAL_UDRE(void);
void __real_system_set_exec_state_flag(uint8_t mask);
void __real_system_clear_exec_state_flag(uint8_t mask);
void __real_system_set_exec_alarm(uint8_t code);
void __real_system_clear_exec_alarm(void);
void __real_system_set_exec_motion_override_flag(uint8_t mask);
void __real_system_set_exec_accessory_override_flag(uint8_t mask);
void __real_system_clear_exec_motion_overrides(void);
void __real_system_clear_exec_accessory_overrides(void);
void __real_grbl_per_tick(void);
void __real_st_prep_buffer(void);
void __real_platform_sleep(long microsec);
void __real_eeprom_put_char(unsigned int addr, unsigned char value);
FILE *eeprom_fp(void);

/* -- 1. stdin ------------------------------------------------------------------------------- */
static unsigned char rx_buf[256];
static int rx_len = 0, rx_pos = 0;
static unsigned rx_calls = 0;

uint8_t __wrap_platform_poll_stdin(void) {
  if (rx_pos >= rx_len) {
    struct pollfd p = {0, POLLIN, 0};
    if ((rx_calls++ & 63) != 0) { return 0; }
    if (poll(&p, 1, 0) <= 0) { return 0; }
    ssize_t n = read(0, rx_buf, sizeof rx_buf);
    if (n <= 0) { _exit(0); }          /* the host is gone: power off */
    rx_len = (int)n;
    rx_pos = 0;
  }
  return rx_buf[rx_pos++];
}

/* -- 6. interrupt atomicity ----------------------------------------------------------------- */
static pthread_mutex_t irq_lock = PTHREAD_MUTEX_INITIALIZER;
#define ATOMIC(call) do { pthread_mutex_lock(&irq_lock); call; pthread_mutex_unlock(&irq_lock); } while (0)

void __wrap_serial_write(uint8_t data) {
  struct timespec pause = {0, 20000};
  while (serial_get_tx_buffer_count() >= TX_BUFFER_SIZE) {   /* ring full: let the handler drain it */
    if (sys_rt_exec_state & EXEC_RESET) { return; }
    nanosleep(&pause, NULL);
  }
  ATOMIC(__real_serial_write(data));
}
void __wrap_interrupt_SERIAL_UDRE(void) { ATOMIC(__real_interrupt_SERIAL_UDRE()); }
void __wrap_system_set_exec_state_flag(uint8_t mask) { ATOMIC(__real_system_set_exec_state_flag(mask)); }
void __wrap_system_clear_exec_state_flag(uint8_t mask) { ATOMIC(__real_system_clear_exec_state_flag(mask)); }
void __wrap_system_set_exec_alarm(uint8_t code) { ATOMIC(__real_system_set_exec_alarm(code)); }
void __wrap_system_clear_exec_alarm(void) { ATOMIC(__real_system_clear_exec_alarm()); }
void __wrap_system_set_exec_motion_override_flag(uint8_t mask) {
  ATOMIC(__real_system_set_exec_motion_override_flag(mask));
}
void __wrap_system_set_exec_accessory_override_flag(uint8_t mask) {
  ATOMIC(__real_system_set_exec_accessory_override_flag(mask));
}
void __wrap_system_clear_exec_motion_overrides(void) { ATOMIC(__real_system_clear_exec_motion_overrides()); }
void __wrap_system_clear_exec_accessory_overrides(void) {
  ATOMIC(__real_system_clear_exec_accessory_overrides());
}

/* -- 3. main-loop check-ins ------------------------------------------------------------------ */
static volatile uint32_t prep_count = 0;

void __wrap_st_prep_buffer(void) {
  __real_st_prep_buffer();
  __atomic_add_fetch(&prep_count, 1, __ATOMIC_RELEASE);
}

/* -- 4. sleeping ----------------------------------------------------------------------------- */
void __wrap_platform_sleep(long microsec) {
  __real_platform_sleep(microsec < 100 ? 100 : microsec);
}

/* -- 5. EEPROM ------------------------------------------------------------------------------- */
void __wrap_eeprom_put_char(unsigned int addr, unsigned char value) {
  __real_eeprom_put_char(addr, value);
  fflush(eeprom_fp());
}

/* -- 2. pins, switches, lockstep ------------------------------------------------------------- */
static int switches_read = 0;
static int has_min[N_AXIS], has_max[N_AXIS];
static float min_mm[N_AXIS], max_mm[N_AXIS];
static int32_t phys_steps[N_AXIS];
static int32_t last_pos[N_AXIS];
static const uint8_t limit_bit[3] = {X_LIMIT_BIT, Y_LIMIT_BIT, Z_LIMIT_BIT};

static void read_switches(void) {
  const char *spec = getenv("LFSTUDIO_GRBL_SIM_SWITCHES");
  int axis = 0;
  switches_read = 1;
  memset(has_min, 0, sizeof has_min);
  memset(has_max, 0, sizeof has_max);
  while (spec && *spec && axis < N_AXIS) {
    char *end;
    float v = strtof(spec, &end);
    if (end != spec) { has_min[axis] = 1; min_mm[axis] = v; spec = end; }
    if (*spec == ':') {
      spec++;
      v = strtof(spec, &end);
      if (end != spec) { has_max[axis] = 1; max_mm[axis] = v; spec = end; }
    }
    while (*spec && *spec != ',') { spec++; }
    if (*spec == ',') { spec++; }
    axis++;
  }
}

static uint8_t limit_pins(void) {
  uint8_t pins = LIMIT_MASK;                   /* pulled up: high = not pressed (normally open) */
  int i;
  for (i = 0; i < N_AXIS && i < 3; i++) {
    float mm = phys_steps[i] / settings.steps_per_mm[i];
    if ((has_min[i] && mm <= min_mm[i]) || (has_max[i] && mm >= max_mm[i])) {
      pins &= ~(1 << limit_bit[i]);
    }
  }
  return pins;
}

static uint32_t lockstep_ticks = 0;
static uint32_t lockstep_seen = 0;

static double wall_s(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return ts.tv_sec + ts.tv_nsec * 1e-9;
}

/* -- 7. spindle output log ------------------------------------------------------------------ */
static int spindle_log_read = 0;
static FILE *spindle_log = NULL;
static int spindle_level = 0;

static void log_spindle(void) {
  int on;
  if (!spindle_log_read) {
    const char *path = getenv("LFSTUDIO_GRBL_SIM_SPINDLE_LOG");
    spindle_log_read = 1;
    if (path && *path) { spindle_log = fopen(path, "w"); }
  }
  if (!spindle_log) { return; }
  on = (SPINDLE_TCCRA_REGISTER & (1 << SPINDLE_COMB_BIT)) && SPINDLE_OCR_REGISTER > 0;
  if (on != spindle_level) {
    spindle_level = on;
    fprintf(spindle_log, "%.7f %d %ld %ld %ld %d\n", (double)sim.masterclock / F_CPU, on, (long)sys_position[0],
            (long)sys_position[1], (long)sys_position[2], (int)SPINDLE_OCR_REGISTER);
    fflush(spindle_log);
  }
}

void __wrap_grbl_per_tick(void) {
  int i;
  __real_grbl_per_tick();
  log_spindle();
  if (!switches_read) {
    read_switches();
    memcpy(last_pos, (const void *)sys_position, sizeof last_pos);
  }
  for (i = 0; i < N_AXIS; i++) {
    int32_t d = sys_position[i] - last_pos[i];
    /* during homing the firmware keeps counting a locked axis without stepping it */
    int locked = sys.state == STATE_HOMING && !(sys.homing_axis_lock & get_step_pin_mask(i));
    if (d >= -1 && d <= 1 && !locked) { phys_steps[i] += d; }  /* larger: a coordinate reset */
    last_pos[i] = sys_position[i];
  }
  CONTROL_PIN |= CONTROL_MASK;
  PROBE_PIN |= PROBE_MASK;
  {
    uint8_t before = LIMIT_PIN & LIMIT_MASK;
    uint8_t after = limit_pins();
    LIMIT_PIN = (LIMIT_PIN & ~LIMIT_MASK) | after;
    if (before != after && (PCICR & (1 << LIMIT_INT)) && (LIMIT_PCMSK & (before ^ after)) && pc_vect) {
      pc_vect();
    }
  }
  if (TIMSK1 & (1 << OCIE1A)) {                 /* the stepper interrupt is running */
    if (++lockstep_ticks >= (uint32_t)(F_CPU / 1000000L * LFSTUDIO_LOCKSTEP_US)) {
      uint32_t now = __atomic_load_n(&prep_count, __ATOMIC_ACQUIRE);
      if (now == lockstep_seen) {
        double give_up = wall_s() + 0.2;       /* never deadlock: 0.2 s of wall time at most */
        struct timespec pause = {0, 20000};
        while (now == lockstep_seen && wall_s() < give_up) {
          nanosleep(&pause, NULL);
          now = __atomic_load_n(&prep_count, __ATOMIC_ACQUIRE);
        }
      }
      lockstep_seen = now;
      lockstep_ticks = 0;
    }
  } else {
    lockstep_ticks = 0;
  }
}
