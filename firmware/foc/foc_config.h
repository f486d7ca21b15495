/* foc_config.h: the build-time settings of the F2812 FOC firmware, as the integers the chip holds.
 *
 * The defaults are the 200 W servo build (bench_configs/servo_200w.toml, hilbench's FocOptions()
 * defaults; derivations in docs/foc.md "Gains"): every IQ value is the truncating _IQ() of the
 * option, computed on the host (hilbench.targets.foc.build.config_values), never in the target's
 * floating point. A build for other options overrides any of them with -DFOC_CFG_NAME=value
 * (hilbench.targets.foc.build.config_defines writes those); tests/test_foc_firmware_c.py checks
 * that these defaults equal FocOptions()'s.
 */
#ifndef FOC_CONFIG_H
#define FOC_CONFIG_H

#ifndef FOC_CFG_PI_FORM
#define FOC_CFG_PI_FORM 0               /* 0 PID_REG3, 1 clamping PI (math_blocks v4.3) */
#endif
#ifndef FOC_CFG_SPEED_FR_UNWRAP
#define FOC_CFG_SPEED_FR_UNWRAP 0       /* 0 SPEED_FR v3.20 (hold near the wrap), 1 v4.3 (unwrap) */
#endif
#ifndef FOC_CFG_LEARN_INDEX
#define FOC_CFG_LEARN_INDEX 1           /* the first index pulse folds T2CNT into CalibratedAngle */
#endif
#ifndef FOC_CFG_QEP_SIGNED16
#define FOC_CFG_QEP_SIGNED16 0
#endif
#ifndef FOC_CFG_LINE_ENCODER
#define FOC_CFG_LINE_ENCODER 2500L
#endif
#ifndef FOC_CFG_POLE_PAIRS
#define FOC_CFG_POLE_PAIRS 3L
#endif
#ifndef FOC_CFG_T2PR
#define FOC_CFG_T2PR 10000L             /* the driver's 4 * LineEncoder */
#endif
#ifndef FOC_CFG_CALIBRATED_ANGLE
#define FOC_CFG_CALIBRATED_ANGLE 0L
#endif
#ifndef FOC_CFG_MECH_SCALER
#define FOC_CFG_MECH_SCALER 107374L     /* _IQ30(0.25 / 2500) */
#endif
#ifndef FOC_CFG_SP_K1
#define FOC_CFG_SP_K1 139810133L        /* _IQ21(1 / (150 Hz * 100 us)) */
#endif
#ifndef FOC_CFG_SP_K2
#define FOC_CFG_SP_K2 16466823L         /* _IQ(1 / (1 + 100 us * 2 pi * 30 Hz)) */
#endif
#ifndef FOC_CFG_SP_K3
#define FOC_CFG_SP_K3 310393L           /* _IQ(1) - K2 */
#endif
#ifndef FOC_CFG_BASE_RPM
#define FOC_CFG_BASE_RPM 3000L
#endif
#ifndef FOC_CFG_SPEED_LOOP_PRESCALER
#define FOC_CFG_SPEED_LOOP_PRESCALER 10L
#endif
#ifndef FOC_CFG_ALIGN_ISRS
#define FOC_CFG_ALIGN_ISRS 2000L        /* 0.2 s */
#endif
#ifndef FOC_CFG_ALIGN_V
#define FOC_CFG_ALIGN_V 503316L         /* _IQ(0.03) */
#endif
#ifndef FOC_CFG_ALIGN_I
#define FOC_CFG_ALIGN_I 3355443L        /* _IQ(1.0 A / 5 A); 0: the fixed alignment voltage */
#endif
#ifndef FOC_CFG_RAMP_STEP
#define FOC_CFG_RAMP_STEP 13981L        /* _IQ(2500 rpm/s / 3000 rpm * 1 ms); 0: no slew */
#endif
#ifndef FOC_CFG_CUR_KP
#define FOC_CFG_CUR_KP 6207569L         /* _IQ(0.37) */
#endif
#ifndef FOC_CFG_CUR_KI
#define FOC_CFG_CUR_KI 1363987L         /* _IQ(0.0813) */
#endif
#ifndef FOC_CFG_CUR_KC
#define FOC_CFG_CUR_KC 3355443L         /* _IQ(0.2) */
#endif
#ifndef FOC_CFG_ID_OUT_MAX
#define FOC_CFG_ID_OUT_MAX 5033164L     /* _IQ(0.3) */
#endif
#ifndef FOC_CFG_IQ_OUT_MAX
#define FOC_CFG_IQ_OUT_MAX 15938355L    /* _IQ(0.95) */
#endif
#ifndef FOC_CFG_SPD_KP
#define FOC_CFG_SPD_KP 11744051L        /* _IQ(0.7) */
#endif
#ifndef FOC_CFG_SPD_KI
#define FOC_CFG_SPD_KI 167772L          /* _IQ(0.01) */
#endif
#ifndef FOC_CFG_SPD_KC
#define FOC_CFG_SPD_KC 3355443L         /* _IQ(0.2) */
#endif
#ifndef FOC_CFG_SPD_OUT_MAX
#define FOC_CFG_SPD_OUT_MAX 8388608L    /* _IQ(0.5): 2.5 A */
#endif

#endif /* FOC_CONFIG_H */
