/* Minimal Cortex-M4F startup for the qemu test image: vector table, FPU on, .data/.bss, C++ constructors,
   semihosting exit with main's return value as the exit code. */
#include <stdint.h>

extern uint32_t _sidata, _sdata, _edata, _sbss, _ebss, _estack;
extern void (*__init_array_start[])(void);
extern void (*__init_array_end[])(void);
int main(void);
void semihost_exit(int code);
void semihost_puts(const char* s);
void SysTick_Handler(void);

void Reset_Handler(void) {
  /* CPACR: full access to CP10/CP11, i.e. the FPU (the M4F starts with it off). */
  *(volatile uint32_t*)0xE000ED88 |= (0xFu << 20);
  __asm volatile("dsb\n isb");
  uint32_t* src = &_sidata;
  for (uint32_t* dst = &_sdata; dst < &_edata;) *dst++ = *src++;
  for (uint32_t* dst = &_sbss; dst < &_ebss;) *dst++ = 0;
  for (void (**f)(void) = __init_array_start; f < __init_array_end; ++f) (*f)();
  semihost_exit(main());
}

static void Fault_Handler(void) {
  semihost_puts("FAULT\n");
  semihost_exit(99);
}

__attribute__((section(".vectors"), used)) static void* const vectors[16] = {
    &_estack, (void*)Reset_Handler, (void*)Fault_Handler, (void*)Fault_Handler, (void*)Fault_Handler,
    (void*)Fault_Handler, (void*)Fault_Handler, 0, 0, 0, 0, (void*)Fault_Handler, 0, 0,
    (void*)Fault_Handler, (void*)SysTick_Handler};

static int semihost(int op, const void* arg) {
  register int r0 __asm("r0") = op;
  register const void* r1 __asm("r1") = arg;
  __asm volatile("bkpt 0xAB" : "+r"(r0) : "r"(r1) : "memory");
  return r0;
}

void semihost_puts(const char* s) { semihost(0x04, s); /* SYS_WRITE0 */ }

void semihost_exit(int code) {
  uint32_t block[2] = {0x20026u /* ADP_Stopped_ApplicationExit */, (uint32_t)code};
  semihost(0x20, block); /* SYS_EXIT_EXTENDED: qemu exits with `code` */
  for (;;) {
  }
}
