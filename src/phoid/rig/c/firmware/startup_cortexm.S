/*
 * startup_cortexm.S -- vector table and reset for Cortex-M3/M4/M7 (ARMv7-M), bare metal:
 * copy .data, zero .bss, enable the FPU where there is one, call main. The linker script
 * (mps2.ld, or your board's) gives _estack, _sidata, _sdata, _edata, _sbss, _ebss.
 */
    .syntax unified
    .thumb

    .section .vectors, "a"
    .align 2
    .globl __vectors
__vectors:
    .word _estack
    .word Reset_Handler
    .word Default_Handler   /* NMI */
    .word Default_Handler   /* HardFault */
    .word Default_Handler   /* MemManage */
    .word Default_Handler   /* BusFault */
    .word Default_Handler   /* UsageFault */
    .word 0, 0, 0, 0
    .word Default_Handler   /* SVCall */
    .word Default_Handler   /* DebugMonitor */
    .word 0
    .word Default_Handler   /* PendSV */
    .word SysTick_Handler

    .text
    .thumb_func
    .globl Reset_Handler
Reset_Handler:
    ldr r0, =_sidata
    ldr r1, =_sdata
    ldr r2, =_edata
1:  cmp r1, r2
    bhs 2f
    ldr r3, [r0], #4
    str r3, [r1], #4
    b 1b
2:  ldr r1, =_sbss
    ldr r2, =_ebss
    movs r3, #0
3:  cmp r1, r2
    bhs 4f
    str r3, [r1], #4
    b 3b
4:
#if defined(__ARM_FP)
    ldr r0, =0xE000ED88     /* CPACR: full access to CP10 and CP11 */
    ldr r1, [r0]
    orr r1, r1, #(0xF << 20)
    str r1, [r0]
    dsb
    isb
#endif
    bl main
5:  b 5b

    .thumb_func
    .weak Default_Handler
Default_Handler:
    b Default_Handler

    .weak SysTick_Handler
    .thumb_set SysTick_Handler, Default_Handler
